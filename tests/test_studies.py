"""The paper studies on the public API: an interrupted clamp study resumes from its record."""

import json

import equinox as eqx
import numpy as np
import pytest
from test_cli import run

import finray_jax as fr
from finray_jax import cli, studies
from finray_jax import io as fio

# Two grasps of Finger-1 (the demo finger): a small study, so the test stays quick.
SETTINGS = dict(diameters=(18.0,), clamp_lengths=(10.0, 30.0))


class _Stop(Exception):
    pass


def _finger():
    finger, _ = fio.load_packaged_finger(cli.DEMO_FINGER)
    return finger


def _grasps(messages):
    return [m for m in messages if "l_c =" in m]


def test_an_interrupted_clamp_study_resumes_without_solving_a_grasp_twice(tmp_path):
    finger = _finger()
    clean = studies.clamp_study(finger, **SETTINGS)
    assert np.all(np.isfinite(clean.normal_force))

    record = tmp_path / "clamp_study.json"
    said = []

    def stop_at_second(msg):
        said.append(msg)
        if len(_grasps(said)) == 2:
            raise _Stop  # interrupted as the second grasp starts

    with pytest.raises(_Stop):
        studies.clamp_study(finger, **SETTINGS, progress=stop_at_second, record=record)
    kept = json.loads(record.read_text())
    assert kept["complete"] is False and kept["solved"] == [[True, False]]
    assert kept["normal_force"][0][0] == pytest.approx(clean.normal_force[0, 0], rel=1e-12)
    assert kept["normal_force"][0][1] is None and "best_clamp_length" not in kept

    said = []
    resumed = studies.clamp_study(finger, **SETTINGS, progress=said.append, record=record)
    assert said[0] == f"continuing {record}: 1 of 2 grasps done"
    assert _grasps(said) == ["18 mm object, l_c = 30 mm"]  # only the one not finished
    np.testing.assert_allclose(resumed.normal_force, clean.normal_force, rtol=1e-12)
    done = json.loads(record.read_text())
    assert done["complete"] is True and done["best_clamp_length"] == clean.best.tolist()

    # Complete: nothing is solved again. Other settings: the record is replaced.
    said = []
    again = studies.clamp_study(finger, **SETTINGS, progress=said.append, record=record)
    assert _grasps(said) == [] and np.array_equal(again.normal_force, resumed.normal_force)
    said = []
    with pytest.raises(_Stop):
        studies.clamp_study(finger, **SETTINGS, closing=5.0, progress=stop_at_second, record=record)
    assert said[0] == f"{record} holds another study (finger or settings differ): starting afresh"
    assert len(_grasps(said)) == 2  # both grasps of the new study were started


def test_a_clamp_study_record_that_is_not_one_is_refused_by_name(tmp_path):
    record = tmp_path / "clamp_study.json"
    record.write_text("not json")
    with pytest.raises(studies.StudyRecordError, match="clamp_study.json: not a clamp-study"):
        studies.clamp_study(_finger(), **SETTINGS, record=record)
    code, _, err = run(["clamp-study", "--out", str(tmp_path)])
    assert code == 1 and "not a clamp-study record" in err and "Traceback" not in err
    assert record.read_text() == "not json"  # left as it was
    record.write_text('{"x": 1}\n')  # JSON, but no study's record
    with pytest.raises(studies.StudyRecordError, match="without a study_hash"):
        studies.clamp_study(_finger(), **SETTINGS, record=record)
    assert record.read_text() == '{"x": 1}\n'


def test_finger_digest_follows_every_value():
    finger = _finger()
    thicker = eqx.tree_at(lambda f: f.back.thickness, finger, finger.back.thickness * 1.001)
    assert studies.finger_digest(finger) == studies.finger_digest(_finger())
    assert studies.finger_digest(thicker) != studies.finger_digest(finger)


@pytest.mark.slow
def test_an_interrupted_comparison_keeps_its_release_traces(tmp_path):
    finger = _finger()
    small = dict(release_diameters=(50.0,), pull_step=4.0)
    clean = studies.compare_adaptors(finger, **small)
    record = tmp_path / "compare_record.json"
    said = []

    def stop_at_second(msg):
        said.append(msg)
        if len([m for m in said if m.startswith("release force")]) == 2:
            raise _Stop

    with pytest.raises(_Stop):
        studies.compare_adaptors(finger, **small, progress=stop_at_second, record=record)
    kept = json.loads(record.read_text())
    assert kept["complete"] is False and list(kept["release"]) == ["50 original"]

    said = []
    resumed = studies.compare_adaptors(finger, **small, progress=said.append, record=record)
    assert said[0] == f"continuing {record}: 1 of 2 release traces done"
    assert [m for m in said if m.startswith("release force")] == [
        "release force, 50 mm object, modified adaptor"
    ]
    for a, b in zip(clean.release[50.0], resumed.release[50.0], strict=True):
        assert b.peak == pytest.approx(a.peak, rel=1e-12) and b.complete == a.complete
        np.testing.assert_allclose(b.force, a.force, rtol=1e-12, atol=1e-12)
    assert resumed.release_gain(50.0) == pytest.approx(clean.release_gain(50.0), rel=1e-12)
    assert json.loads(record.read_text())["complete"] is True


def test_grasp_by_actuator_force_meets_the_force_after_stiffening():
    """grasp(actuator_force=F) at the F that closing by 6 mm needs: the contact is
    stiffened on the way, and the closing is found again for the stiffer contact (it used
    to stop at the closing found before, 6.36 mm, and miss F by 1.7 %, reported converged)."""
    design = _modified(18.0, 10.0)
    g = studies.grasp(design, 6.0)
    force = float(g.contact.actuator_force)
    by_force = studies.grasp(design, actuator_force=force)
    assert by_force.converged
    assert float(by_force.contact.actuator_force) == pytest.approx(force, rel=1e-7)
    # (6 mm less what the penalty stiffness, stiffened to another value than at 6 mm,
    # moves: 0.0045 mm)
    assert float(by_force.closing) == pytest.approx(6.0, abs=0.01)


def test_grasp_by_actuator_force_finds_the_closing_that_gives_it():
    """With a fixed penalty, grasp(actuator_force=F) at the F of a 4 mm closing closes 4
    mm again; a zero force leaves the finger open (closing 0, no contact)."""
    design = _modified(18.0, 10.0)
    g = studies.grasp(design, 4.0, stiffen=False)
    force = float(g.contact.actuator_force)
    assert force > 0
    by_force = studies.grasp(design, actuator_force=force, stiffen=False)
    assert by_force.converged
    assert float(by_force.contact.actuator_force) == pytest.approx(force, rel=1e-7)
    assert float(by_force.closing) == pytest.approx(4.0, abs=1e-6)
    np.testing.assert_allclose(
        np.asarray(by_force.solution.unknowns), np.asarray(g.solution.unknowns), atol=1e-6
    )
    none = studies.grasp(design, actuator_force=0.0, stiffen=False)
    assert none.converged and float(none.closing) == 0.0
    assert float(none.contact.normal_force) == 0.0


def test_an_actuator_force_beyond_the_fingers_peak_returns_the_peak():
    """Finger-1 on the modified adaptor with the back beam not clamped (l_c = 0) pushes
    the 18 mm cylinder with at most about 14.56 N, near 5.4 mm of closing (the force then
    falls: the finger gives way). Asked for 15 N, the grasp fails with
    actuator_force_not_reached and returns the peak: the force there beats the closings
    0.05 mm to either side, and the study says so in its progress line."""
    design = _modified(18.0, 0.0)
    g = studies.grasp(design, actuator_force=15.0)
    assert not g.converged
    assert g.solution.result == studies.RESULTS.actuator_force_not_reached
    peak, t = float(g.contact.actuator_force), float(g.closing)
    assert 14.0 < peak < 15.0 and 4.5 < t < 6.5
    for side in (t - 0.05, t + 0.05):
        near = studies.grasp(design, side, stiffen=False)
        assert near.converged and float(near.contact.actuator_force) < peak
    why = studies._why_not(g, 15.0)
    assert why.startswith(f"the actuator force peaks at {peak:.4g} N, at closing {t:.4g} mm")


def test_the_open_finger_is_clear_of_the_objects_before_the_estimated_contact():
    """_closing_to_contact: a closing that leaves a cylinder 2 mm in front of the straight
    front beam clear of it, short of that 2 mm by at most the samples' spacing."""
    from finray_jax._closing import _closing_to_contact
    from finray_jax._geometry import main_beam_samples
    from finray_jax._grasp_inputs import with_objects_moved

    design = studies.with_object(_finger(), 18.0, clearance=2.0)
    gap = _closing_to_contact(design)
    assert 2.0 - 130.0 / 400 <= gap <= 2.0
    for closing in (gap, 2.0 - 1e-9):  # clear up to the first contact, however sampled
        moved = with_objects_moved(design, np.array([closing, 0.0]))
        _, p, h = (np.asarray(x) for x in main_beam_samples(moved, 24001))
        assert np.min(np.asarray(moved.objects[0].signed_distance(p)) - h) > 0


def _modified(diameter, clamp_length):
    ad = studies.Adaptor(
        front_base=fr.PinnedBase(), back_clamp_length=clamp_length, support_length=60.0
    )
    return studies.with_adaptor(studies.with_object(_finger(), diameter), ad)


@pytest.mark.slow
def test_clamp_study_at_equal_actuator_force_by_holding_force(tmp_path):
    """Held at the actuator force that the l_c = 10 mm grasp needs to close 6 mm, the
    study closes that design by about 6 mm again and the stiffer l_c = 30 mm design less;
    with holding=True the best clamp length is the one with the larger holding force, and
    a resumed study takes the holding forces from its record."""
    force = float(studies.grasp(_modified(18.0, 10.0), 6.0).contact.actuator_force)
    record = tmp_path / "clamp_study.json"
    said = []
    kwargs = dict(actuator_force=force, holding=True, friction=0.3, record=record)
    st = studies.clamp_study(_finger(), **SETTINGS, **kwargs, progress=said.append)
    assert st.measure == "holding force" and st.actuator_force == force
    assert st.closing[0, 0] == pytest.approx(6.0, abs=0.01)
    assert st.closing[0, 1] < st.closing[0, 0]  # (stiffer: closes less for the same force)
    assert np.all(np.isfinite(st.holding_force)) and np.all(st.holding_force > 0)
    assert st.best[0] == st.clamp_lengths[np.argmax(st.holding_force[0])]
    assert sum("release trace (mu = 0.3)" in m for m in said) == 2
    said = []
    again = studies.clamp_study(_finger(), **SETTINGS, **kwargs, progress=said.append)
    assert _grasps(said) == [] and np.array_equal(again.holding_force, st.holding_force)
    rec = json.loads(record.read_text())
    assert rec["closing"] is None and rec["actuator_force"] == force and rec["friction"] == 0.3
    assert rec["closing_reached"] == st.closing.tolist()
    assert rec["best_clamp_length"] == st.best.tolist()


def test_clamp_study_best_is_nan_where_no_grasp_of_a_size_converged():
    """A size with no converged grasp has no best clamp length (NaN, not the first one).
    The holding force, when measured, decides over the contact force."""
    lc = np.array([0.0, 10.0, 20.0])
    force = np.array([[np.nan, np.nan, np.nan], [1.0, 3.0, 2.0]])
    st = studies.ClampStudy(np.array([18.0, 35.0]), lc, 60.0, force)
    assert np.isnan(st.best[0]) and st.best[1] == 10.0 and st.measure == "contact force"
    held = studies.ClampStudy(
        np.array([18.0, 35.0]), lc, 60.0, force, holding_force=np.array([[1.0, 0.5, 2.0]] * 2)
    )
    assert held.best.tolist() == [20.0, 20.0] and held.measure == "holding force"


@pytest.mark.parametrize(
    "settings, words",
    [
        (dict(diameters=()), "diameters must be one or more positive sizes (mm), got []"),
        (dict(diameters=(18.0, -1.0)), "diameters must be one or more positive sizes"),
        (dict(clamp_lengths=(float("nan"),)), "clamp_lengths must be one or more lengths"),
        (dict(clamp_lengths=(10.0, 61.0)), "clamp_lengths must lie in [0, support_length = 60.0]"),
    ],
)
def test_a_clamp_study_grid_is_checked_before_any_grasp(settings, words):
    said = []
    with pytest.raises(ValueError) as e:
        studies.clamp_study(_finger(), **settings, progress=said.append)
    assert words in str(e.value) and not _grasps(said)
