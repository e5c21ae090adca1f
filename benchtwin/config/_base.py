"""Loading TOML scenario files into validated pydantic models with one-line error messages."""

from __future__ import annotations

import difflib
import tomllib
from pathlib import Path
from typing import Any, TypeVar

from pydantic import BaseModel, ConfigDict, ValidationError

from benchtwin.errors import ConfigError

__all__ = ["StrictModel", "load_model", "read_toml", "scenario_path", "validate_data"]

M = TypeVar("M", bound=BaseModel)

#: where the shipped scenario files live (inside the source tree and the installed package)
SCENARIO_ROOTS: tuple[Path, ...] = (
    Path(__file__).resolve().parents[2] / "scenarios",
    Path(__file__).resolve().parents[1] / "scenarios",
)


class StrictModel(BaseModel):
    """Base of every scenario model: unknown keys are errors, values are validated on assignment.

    NaN and infinity are refused in every float field of every model (nested tables and lists
    included): ``nan`` and ``inf`` are valid TOML but never a valid bench or vehicle value.
    """

    model_config = ConfigDict(extra="forbid", validate_assignment=True, frozen=False, populate_by_name=True,
                              allow_inf_nan=False)


def scenario_path(*parts: str) -> Path:
    """Return the path of a shipped scenario file, e.g. ``scenario_path('vehicles', 'p2_phev_9at.toml')``.

    Raises
    ------
    ConfigError
        If no shipped file has that name.
    """
    for root in SCENARIO_ROOTS:
        p = root.joinpath(*parts)
        if p.exists():
            return p
    raise ConfigError(f"no shipped scenario file {'/'.join(parts)!r}")


def _data_loc(data: Any, loc: tuple[Any, ...]) -> tuple[Any, ...]:
    """``loc`` without the tags pydantic inserts for a discriminated union (``tests.0.ramp_up.gear``).

    A string step that is not a key of the table at that point but is the value of its ``kind`` is such
    a tag: the user wrote ``tests[0].gear``.
    """
    out: list[Any] = []
    cur = data
    for item in loc:
        if isinstance(cur, dict) and isinstance(item, str) and item not in cur and cur.get("kind") == item:
            continue
        out.append(item)
        try:
            cur = cur[item]
        except (KeyError, IndexError, TypeError):
            cur = None
    return tuple(out)


def _fmt_loc(loc: tuple[Any, ...]) -> str:
    out = ""
    for item in loc:
        if isinstance(item, int):
            out += f"[{item}]"
        else:
            out += ("." if out else "") + str(item)
    return out or "<root>"


_MISSING = object()


def _lookup(data: Any, loc: tuple[Any, ...]) -> Any:
    cur = data
    for item in loc:
        try:
            cur = cur[item]
        except (KeyError, IndexError, TypeError):
            return _MISSING
    return cur


def _model_fields_at(model: type[BaseModel], loc: tuple[Any, ...]) -> list[str]:
    """Best-effort list of allowed keys of the sub-model at ``loc`` (for 'did you mean')."""
    cur: Any = model
    for item in loc[:-1]:
        if isinstance(item, int) or not (isinstance(cur, type) and issubclass(cur, BaseModel)):
            continue
        field = cur.model_fields.get(str(item))
        if field is None:
            return []
        ann = field.annotation
        args = getattr(ann, "__args__", ()) or ()
        cands = [ann, *args]
        for sub in args:
            cands.extend(getattr(sub, "__args__", ()) or ())
        nxt = next((c for c in cands if isinstance(c, type) and issubclass(c, BaseModel)), None)
        if nxt is None:
            return []
        cur = nxt
    if isinstance(cur, type) and issubclass(cur, BaseModel):
        return list(cur.model_fields)
    return []


def format_validation_error(exc: ValidationError, source: str, data: Any, model: type[BaseModel]) -> str:
    """Turn a pydantic ValidationError into one line per problem naming file, key, value, fix."""
    lines = []
    for err in exc.errors():
        raw_loc = tuple(err.get("loc", ()))
        loc = _data_loc(data, raw_loc)
        key = _fmt_loc(loc)
        typ = err.get("type", "")
        if typ == "extra_forbidden":
            allowed = _model_fields_at(model, raw_loc)
            hint = ""
            close = difflib.get_close_matches(str(loc[-1]), allowed, n=1, cutoff=0.5) if loc else []
            if close:
                hint = f"; did you mean {close[0]!r}? (units are part of the key name)"
            elif allowed:
                hint = f"; allowed keys here: {', '.join(allowed)}"
            lines.append(f"{source}: unknown key {key!r}{hint}")
        elif typ == "missing":
            lines.append(f"{source}: missing key {key!r}: it is required")
        elif not loc or isinstance(_lookup(data, loc), dict | list):  # a whole table: its own message says where
            msg = str(err.get("msg", "invalid value")).removeprefix("Value error, ")
            lines.append(f"{source}: {'' if not loc else key + ': '}{msg}")
        else:
            value = _lookup(data, loc)
            msg = err.get("msg", "invalid value")
            if typ == "finite_number":
                msg = "nan and inf are not allowed; give a finite number"
            shown = "" if value is _MISSING else f" = {value!r}"
            lines.append(f"{source}: key {key!r}{shown}: {msg}")
    return "\n".join(lines)


def validate_data(model: type[M], data: Any, source: str = "<data>") -> M:
    """Validate a mapping against ``model``; raise :class:`ConfigError` with readable lines."""
    try:
        return model.model_validate(data)
    except ValidationError as exc:
        raise ConfigError(format_validation_error(exc, source, data, model)) from None


def read_toml(path: str | Path) -> dict[str, Any]:
    """Read a TOML file into a dict.

    Raises
    ------
    ConfigError
        File missing, a folder, not UTF-8, unreadable or not TOML; one line naming the file.
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ConfigError(f"{path}: no such file") from None
    except IsADirectoryError:
        raise ConfigError(f"{path}: is a folder, not a TOML file") from None
    except UnicodeDecodeError as exc:
        raise ConfigError(f"{path}: not UTF-8 text (byte 0x{exc.object[exc.start]:02x} at offset {exc.start}); "
                          "TOML files must be saved as UTF-8") from None
    except OSError as exc:
        raise ConfigError(f"{path}: cannot be read ({exc.strerror})") from None
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{path}: not valid TOML ({exc})") from None


def load_model(model: type[M], path: str | Path) -> M:
    """Read a TOML file and validate it as ``model``.

    Raises
    ------
    ConfigError
        File missing, not UTF-8, not TOML, or not valid for the model; the message names the file and key.
    """
    return validate_data(model, read_toml(path), str(path))
