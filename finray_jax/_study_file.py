"""Study files (sweeps, optimisations): TOML files that name a base finger file.

The study's own parser reads the document; these helpers read the text, parse the TOML
and load the base finger, with every error raised as the study's own error class.
"""

from __future__ import annotations

import hashlib
import os

from ._finger_file import load_finger
from ._toml_reader import FingerFileError, TomlReader, parse_toml, read_text


def loads_study(text: str, parse, error: type[FingerFileError], source: str, base_dir: str):
    """Parse a study file's TOML with `parse(doc, reader, source, base_dir)`; every
    FingerFileError (its own or its base finger's) comes out as `error`."""
    r = TomlReader(source)
    doc = parse_toml(text, source, error)
    try:
        return parse(doc, r, source, base_dir)
    except error:
        raise
    except FingerFileError as e:
        raise error(str(e)) from None


def load_study(path, loads, what: str, error: type[FingerFileError]):
    """Read the study file at `path` with `loads(text, source=, base_dir=)`."""
    path = os.fspath(path)
    text = read_text(path, what, error)
    return loads(text, source=path, base_dir=os.path.dirname(os.path.abspath(path)))


def base_finger(doc: dict, r: TomlReader, base_dir: str):
    """The finger file a study names (key `finger`, relative to the study file):
    (finger, settings, normalised path, sha256 of its bytes)."""
    rel = r.string(doc["finger"], "finger")
    path = os.path.normpath(os.path.join(base_dir, rel))
    if not os.path.isfile(path):
        raise r.error("finger", f"no such finger file: {path}", rel)
    finger, settings = load_finger(path)
    with open(path, "rb") as fh:
        digest = hashlib.sha256(fh.read()).hexdigest()
    return finger, settings, path, digest
