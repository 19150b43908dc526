"""The design explorer's server-side session (no web library): one `Explorer` shared by
every page, one worker thread that runs its solves one at a time (a page never waits on a
solve: it hands the job over and is called back), and the preparation at start-up that
compiles the first design's programs while the page says so."""

from __future__ import annotations

import queue
import threading
import time
import traceback

from ._errors import FingerError
from ._explore_design import Choices, ControlError, choices_of, values_of
from ._explore_grad import sensitivities
from ._explore_model import Explorer
from ._explore_views import view_of
from .design import DesignError

# What a refused design raises: shown on the page as it is.
REFUSED = (ControlError, FingerError, DesignError, ValueError)


class Worker:
    """One daemon thread that runs jobs in order (jax solves, one at a time)."""

    def __init__(self):
        self.jobs: queue.Queue = queue.Queue()
        threading.Thread(target=self._run, name="finray-explore", daemon=True).start()

    def submit(self, job) -> None:
        self.jobs.put(job)

    def _run(self) -> None:
        while True:
            job = self.jobs.get()
            try:
                job()
            except Exception:  # (a job reports its own errors; this keeps the thread alive)
                traceback.print_exc()
            finally:
                self.jobs.task_done()

    def wait_idle(self, seconds: float) -> bool:
        """Wait until every job handed over has finished (at most `seconds`)."""
        t0 = time.monotonic()
        while self.jobs.unfinished_tasks and time.monotonic() - t0 < seconds:
            time.sleep(0.05)
        return not self.jobs.unfinished_tasks


class App:
    """The explorer behind the page: the finger file's design, the shared `Explorer`, its
    worker, and the preparation's progress (`preparing`: what is being compiled, "" when
    ready; `error`: why the first design could not be solved)."""

    def __init__(self, finger, grasp_settings=None, source: str = "", say=print):
        self.source = source
        self.explorer = Explorer(finger, grasp_settings)
        gs = grasp_settings
        self.choices: Choices = choices_of(finger, gs is not None and gs.actuator_force is not None)
        self.values: dict = values_of(
            finger,
            None if gs is None else gs.closing,
            None if gs is None else gs.actuator_force,
            None if gs is None else gs.friction,
        )
        self.worker = Worker()
        self.preparing = "starting"
        self.error = ""
        self.first = None  # the first design's State
        self.first_view = None  # and its View
        self.say = say
        self.prepare_seconds = float("nan")

    def prepare(self) -> None:
        """Solve the first design and its sensitivities (compiling their programs), on the
        worker; `preparing` says which step runs."""
        self.worker.submit(self._prepare)

    def _prepare(self) -> None:
        t0 = time.perf_counter()
        try:
            self.preparing = "compiling the contact solver and solving the first grasp"
            if self.choices.mode != "grasp":
                self.preparing = "compiling the solver and solving the load case"
            state = self.explorer.solve(self.choices, self.values)
            if not state.converged:
                raise FingerError(f"the first design did not converge: {state.message}")
            self.preparing = "compiling the gradients (sensitivities in every design value)"
            self.explorer.sensitivities = sensitivities(self.explorer, state)
            # A slider's solve (from the previous equilibrium) and the view, compiled now
            self.preparing = "compiling the warm-started solve and the views"
            state = self.explorer.solve(self.choices, self.values)
            self.first_view = view_of(state, self.explorer.symmetric)
            self.first = state
        except REFUSED as e:
            self.error = str(e)
        self.prepare_seconds = time.perf_counter() - t0
        self.say(f"ready after {self.prepare_seconds:.0f} s" if not self.error else self.error)
        self.preparing = ""

    @property
    def ready(self) -> bool:
        return not self.preparing and self.first is not None
