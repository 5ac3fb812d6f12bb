"""TOML helpers shared by every configuration object (geometry, washout, calibration).

Reading uses the standard library's :mod:`tomllib`; writing uses ``tomli_w``.
Every failure becomes a :class:`~motionbase.errors.ConfigError` whose message
names the file, the field and the fix.
"""

from __future__ import annotations

import importlib
import math
import os
import stat
import tomllib
from collections.abc import Iterable, Mapping
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np
import tomli_w

from motionbase.errors import ConfigError

#: The largest configuration file read, bytes: a file past it is not one (a device such as
#: /dev/zero or /dev/urandom never ends, and was read until the memory ran out).
MAX_TOML_BYTES = 16 * 1024 * 1024

#: The text of each pipe read so far, by (device, inode): a pipe (``--platform <(cat
#: rig.toml)``) can be read once, and a command reads a geometry file more than once (to
#: tell which robot it is for, then to load it). A second read found it empty.
_PIPES_READ: dict[tuple[int, int], bytes] = {}


def _read_bytes(p: Path) -> bytes:
    """At most ``MAX_TOML_BYTES + 1`` bytes of a file; a pipe's only once."""
    with p.open("rb") as fh:
        st = os.fstat(fh.fileno())
        key = (st.st_dev, st.st_ino)
        if stat.S_ISFIFO(st.st_mode) and key in _PIPES_READ:
            return _PIPES_READ[key]
        raw = fh.read(MAX_TOML_BYTES + 1)
    if stat.S_ISFIFO(st.st_mode):
        _PIPES_READ[key] = raw
    return raw


def read_toml(path: str | Path) -> dict[str, Any]:
    """Read a TOML file, turning a missing file or a syntax error into ConfigError."""
    p = Path(path)
    try:
        raw = _read_bytes(p)
        if len(raw) > MAX_TOML_BYTES:
            raise ConfigError(
                f"{p}: larger than {MAX_TOML_BYTES // 2**20} MB, not a configuration file "
                "(give a .toml file)"
            )
        # A byte-order mark (Windows Notepad writes one) is not TOML; take the text after it.
        return tomllib.loads(raw.removeprefix(b"\xef\xbb\xbf").decode("utf-8"))
    except FileNotFoundError:
        raise ConfigError(f"{p}: file not found (check the path)") from None
    except IsADirectoryError:
        raise ConfigError(f"{p}: is a directory, expected a .toml file") from None
    except PermissionError:
        raise ConfigError(f"{p}: permission denied (check the file's permissions)") from None
    except OSError as exc:  # a read that fails (EIO: a failing disk or stick)
        raise ConfigError(f"{p}: cannot read: {exc.strerror or exc}") from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{p}: not valid TOML: {exc} (fix the syntax there)") from None
    except UnicodeDecodeError as exc:
        line = exc.object[: exc.start].count(b"\n") + 1
        raise ConfigError(
            f"{p}: not a text TOML file (not UTF-8 on line {line}: save it as UTF-8)"
        ) from None


def write_toml(path: str | Path, data: Mapping[str, Any]) -> None:
    """Write plain data (numbers, strings, lists, tables; numpy values allowed) to TOML."""
    p = Path(path)
    try:
        with p.open("wb") as fh:
            tomli_w.dump(_plain(data), fh)
    except OSError as exc:
        raise ConfigError(f"{p}: cannot write: {exc.strerror}") from None


#: The 6-RUS geometry every command uses when none is named.
DEFAULT_RUS6 = "ceart"
#: The 3-RRR geometry every command uses when none is named (``fly --planar``, ``stream
#: --planar``, ``teleop``, ``workspace --planar``): the thesis's robot with its servo horns
#: remounted for the well-conditioned working mode (``udesc`` is the robot as built).
DEFAULT_RRR3 = "udesc_symmetric"


def _preset_dir() -> Path:
    return Path(str(resources.files("motionbase") / "presets"))


def preset_names(kind: str, folder: str | Path | None = None) -> list[str]:
    """The names of the presets shipped for ``kind`` (``<kind>_<name>.toml``), sorted.

    ``folder``: where they are, for a plug-in that ships its own (default: motionbase's
    ``presets``)."""
    where = _preset_dir() if folder is None else Path(folder)
    return sorted(q.name[len(kind) + 1 : -5] for q in where.glob(f"{kind}_*.toml"))


def preset_path(kind: str, name: str, folder: str | Path | None = None) -> Path:
    """Path of a preset shipped in ``motionbase/presets/<kind>_<name>.toml`` (or in
    ``folder``, a plug-in's own presets)."""
    candidate = (_preset_dir() if folder is None else Path(folder)) / f"{kind}_{name}.toml"
    if not os.path.isfile(candidate):  # (pathlib's raises for a name too long)
        known = preset_names(kind, folder)
        raise ConfigError(
            f"unknown {kind} preset {name!r}: choose one of {', '.join(known) or '(none)'} "
            "or give a path to a .toml file"
        )
    return candidate


def names_a_file(name_or_path: str | Path, folders: Iterable[str | Path | None] = ()) -> bool:
    """True when a preset-or-path value is a path (``my.toml``, ``dir/x``, an existing file),
    not a preset name (``ceart``).

    ``folders``: more preset folders than motionbase's own (plug-ins' presets; None is
    skipped), whose names a file in the working directory must not shadow either.

    Raises
    ------
    ConfigError
        A bare name that is both a file in the working directory and a preset (of any
        kind): which one is meant cannot be told, and a stray file must not silently
        replace a preset.
    """
    s = str(name_or_path)
    if s.endswith(".toml") or "/" in s:
        return True
    if not os.path.isfile(s):  # (pathlib's raises for a name too long)
        return False
    for folder in (_preset_dir(), *(Path(f) for f in folders if f is not None)):
        if any(q.stem.partition("_")[2] == s for q in folder.glob("*.toml")):
            shipped = "shipped " if folder == _preset_dir() else ""
            raise ConfigError(
                f"{s!r} is both a {shipped}preset and a file in the working directory: write "
                f"./{s} for the file, or rename it to use the preset"
            )
    return True


def resolve_preset_or_path(
    kind: str, name_or_path: str | Path, folder: str | Path | None = None
) -> Path:
    """A preset name (``ceart``) or a path to a TOML file (``my.toml``); ``folder``: where
    the presets are, for a plug-in's own (default: motionbase's)."""
    if names_a_file(name_or_path, (folder,)):
        return Path(name_or_path)
    return preset_path(kind, str(name_or_path), folder)


def refuse_out_over_inputs(
    out: str | Path, *given: tuple[str, str | Path | None], writing: str = "the log"
) -> None:
    """A ConfigError when ``--out`` names a file the run reads (``(flag, path)`` pairs; a
    path that is None or no file, a preset's name, is skipped): ``writing`` (what goes to
    ``--out``) would overwrite it. One file through symlinks, ``..`` and hard links counts."""
    for flag, path in given:
        if path is not None and os.path.isfile(path) and same_file(path, out):
            raise ConfigError(
                f"--out {out} is the {flag} file ({path}): writing {writing} would destroy it; "
                "give another file"
            )


def same_file(a: str | Path, b: str | Path) -> bool:
    """Whether two paths name one existing file (through symlinks, ``..`` and hard links)."""
    try:
        return os.path.samefile(a, b)
    except OSError:  # one of them does not exist (yet)
        return False


def import_plugin(ref: str, what: str) -> Any:
    """The class a plug-in registration names, ``"module:Name"`` (or ``"module.Name"``).

    A module that will not import (not installed, or failing its own imports) or a name it
    does not define is a ConfigError naming the plug-in ``what`` and the reference, not a
    traceback: a registered plug-in whose package is missing is a set-up mistake.
    """
    module_name, sep, attr = ref.partition(":")
    if not sep:
        module_name, _, attr = ref.rpartition(".")
    try:
        obj: Any = importlib.import_module(module_name)
    except ImportError as exc:
        raise ConfigError(
            f"{what}: cannot import {ref!r}: {exc} (install the plug-in's package or fix its "
            "registration)"
        ) from None
    for part in attr.split(".") if attr else ():
        if not hasattr(obj, part):
            raise ConfigError(
                f"{what}: cannot import {ref!r}: {module_name!r} has no {part!r} (fix the "
                "plug-in's registration)"
            )
        obj = getattr(obj, part)
    return obj


def check_keys(
    source: str, table: Mapping[str, Any], allowed: Iterable[str], required: Iterable[str] = ()
) -> None:
    """Reject unknown keys and report missing required ones, by name."""
    allowed = set(allowed)
    unknown = sorted(set(table) - allowed)
    if unknown:
        raise ConfigError(
            f"{source}: unknown field {unknown[0]!r}: remove it or fix its spelling "
            f"(known fields: {', '.join(sorted(allowed))})"
        )
    missing = [k for k in required if k not in table]
    if missing:
        raise ConfigError(f"{source}: missing field {missing[0]!r} (add it)")


def is_number(value: Any) -> bool:
    """True for an int or float (numpy's too); False for bool, strings and everything else."""
    return isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(
        value, (bool, np.bool_)
    )


def to_float(value: Any) -> float:
    """``float(value)``, a whole number too large for a float (TOML and JSON integers have
    no bound: ``1`` and 400 zeros) taken as the infinity of its sign, so that the finiteness
    checks refuse it by name instead of an OverflowError."""
    try:
        return float(value)
    except OverflowError:
        return math.inf if value > 0 else -math.inf


def as_float(
    source: str,
    name: str,
    value: Any,
    *,
    min_value: float | None = None,
    strict_min: bool = False,
    unit: str = "",
) -> float:
    """Validate a finite scalar (a number: never a bool or a string), optionally bounded below."""
    if not is_number(value):
        raise ConfigError(f"{source}: field {name!r}: expected a number, got {value!r}")
    v = to_float(value)
    if not np.isfinite(v):
        got = "a whole number too large for a float" if isinstance(value, int) else v
        raise ConfigError(f"{source}: field {name!r}: must be finite, got {got}")
    if min_value is not None:
        bad = v <= min_value if strict_min else v < min_value
        if bad:
            op = ">" if strict_min else ">="
            raise ConfigError(
                f"{source}: field {name!r}: must be {op} {min_value:g}{unit and ' ' + unit}, "
                f"got {v:g} (fix the value)"
            )
    return v


def as_array(source: str, name: str, value: Any, length: int) -> np.ndarray:
    """Validate a list of exactly ``length`` finite numbers (or one number for all of them).

    Types are strict: a bool, a string or a list holding one is refused, never converted
    (``true`` is not 1.0, ``"0.5"`` is not 0.5).
    """
    what = f"{source}: field {name!r}: expected {length} numbers"
    if is_number(value):
        arr = np.full(length, to_float(value))
    elif isinstance(value, np.ndarray) and value.dtype.kind in "iuf":
        arr = value.astype(float)
        if arr.ndim == 0:
            arr = np.full(length, float(arr))
    elif isinstance(value, (list, tuple, np.ndarray)):
        items = list(value)
        for item in items:
            if not is_number(item):
                raise ConfigError(f"{what}, got {item!r} in {_short(value)} (write a number)")
        arr = np.array([to_float(v) for v in items], dtype=float)
    else:
        raise ConfigError(f"{what} (or one number for all), got {_short(value)}")
    if arr.shape != (length,):
        raise ConfigError(f"{what}, got {arr.size} (fix the list length)")
    if not np.isfinite(arr).all():
        raise ConfigError(f"{source}: field {name!r}: every value must be finite")
    return arr


def _short(value: Any, limit: int = 60) -> str:
    text = repr(value.tolist() if isinstance(value, np.ndarray) else value)
    return text if len(text) <= limit else text[: limit - 3] + "..."


# Fields that only one kind of configuration file has, and what to do with such a file.
_FILE_KINDS: dict[str, tuple[frozenset[str], str]] = {
    "washout": (
        frozenset({"scaling", "translational", "tilt", "rotational"}),
        "a washout parameter file (give it with --washout)",
    ),
    "mpc": (
        frozenset({"horizon", "weights", "limits", "reference", "robot", "solver"}),
        "an MPC cueing parameter file (give it with --cueing mpc --params)",
    ),
    "rus6": (
        frozenset(
            {"rb", "rp", "chi_a", "chi_a_deg", "chi_j", "chi_j_deg", "beta", "beta_deg"}
            | {"neutral_height", "neutral_angle_deg", "angle_min", "angle_min_deg"}
        ),
        "a 6-RUS geometry file (a --platform, without --planar)",
    ),
    "rrr3": (
        frozenset({"base_side", "platform_side", "modes", "servo", "safety"}),
        "a 3-RRR geometry file (a --platform with --planar; teleop's --rrr3)",
    ),
    "stewart6": (
        frozenset(
            {"base_radius", "platform_radius", "base_half_angle", "base_half_angle_deg"}
            | {"platform_half_angle", "platform_half_angle_deg", "neutral_length"}
            | {"length_min", "length_max", "park_margin"}
        ),
        "a 6-UPS Stewart platform geometry file (a --platform, without --planar)",
    ),
}
_KIND_NAMES = {
    "washout": "washout parameters",
    "mpc": "MPC parameters",
    "rus6": "a 6-RUS geometry",
    "rrr3": "a 3-RRR geometry",
    "stewart6": "a 6-UPS Stewart platform geometry",
}


def file_kind(table: Any) -> str | None:
    """Which kind of configuration file a parsed table is (a key of the file kinds:
    ``"washout"``, ``"mpc"``, ``"rus6"``, ``"rrr3"``, ``"stewart6"``), or None when it
    cannot tell.

    A ``kind`` field naming one decides; otherwise the kind whose own fields it has (the
    one with the most of them).
    """
    if not isinstance(table, Mapping):
        return None
    declared = table.get("kind")
    if isinstance(declared, str) and declared in _FILE_KINDS:
        return declared
    keys = set(table)
    score = {k: len(keys & marks) for k, (marks, _) in _FILE_KINDS.items()}
    best = max(score, key=score.__getitem__)
    return best if score[best] > 0 else None


def describe_file_kind(kind: str) -> str:
    """What a kind of :func:`file_kind` is, for a message: ``"a washout parameter file (give
    it with --washout)"``."""
    return _FILE_KINDS[kind][1]


def check_file_kind(source: str, table: Any, expected: str) -> None:
    """Refuse a table that is plainly another kind of file (a washout file as a geometry...).

    Parameters
    ----------
    source : str
        Named in the message (the file).
    table : mapping
        The parsed file.
    expected : str
        What the caller reads: ``"washout"``, ``"mpc"``, ``"rus6"``, ``"rrr3"``,
        ``"stewart6"``, or a plug-in robot's name (its geometry files are then told apart
        from the kinds above by their ``kind`` field and those kinds' fields).

    Raises
    ------
    ConfigError
        ``table`` has fields only another kind of file has and none of ``expected``'s, or
        more of another kind's than of ``expected``'s (its ``kind`` field, if it says
        ``expected``, is then named as the fault).
    """
    if not isinstance(table, Mapping):
        return
    keys = set(table)
    score = {k: len(keys & marks) for k, (marks, _) in _FILE_KINDS.items()}
    declared = table.get("kind")
    if expected not in _FILE_KINDS:  # a plug-in robot's kind: its fields are not known here
        if declared == expected:
            return
        # and it may share the shipped geometries' generic names (length_min): only their
        # kind field, or a cueing file's tables, tell another file apart
        score = {k: v if k in ("washout", "mpc") else 0 for k, v in score.items()}
        score[expected] = 0
    if score[expected] and max(score.values()) == score[expected]:
        return  # its own fields are there: the field checks say what is wrong
    # the other kinds whose fields it has, the one with the most of them first (an MPC file
    # has a [tilt] table as a washout file does, and five tables only it has)
    found = sorted((k for k in score if k != expected and score[k]), key=lambda k: -score[k])
    if isinstance(declared, str) and declared in _FILE_KINDS and declared != expected:
        found.insert(0, declared)
    if not found:
        return
    other = found[0]
    if declared == expected:  # the fields say otherwise: the kind is what is wrong
        raise ConfigError(
            f"{source}: field 'kind': {declared!r}, but the other fields are those of "
            f"{_FILE_KINDS[other][1]}; fix kind = {other!r} or the fields"
        )
    wanted = _KIND_NAMES.get(expected, f"a {expected} geometry")
    raise ConfigError(f"{source}: this is {_FILE_KINDS[other][1]}, not {wanted}")


def _plain(obj: Any) -> Any:
    if isinstance(obj, Mapping):
        return {str(k): _plain(v) for k, v in obj.items()}
    if isinstance(obj, np.ndarray):
        return [_plain(v) for v in obj.tolist()]
    if isinstance(obj, (list, tuple)):
        return [_plain(v) for v in obj]
    if isinstance(obj, np.generic):
        return obj.item()
    return obj
