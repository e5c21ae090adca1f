"""Typed names of fits and parameters: one place builds ``transmission.gear5_coast`` and one parses it.

A fit of an :class:`~benchtwin.identification._fit.IdentificationResult` is keyed by the string of its
:class:`FitKey`; a parameter by ``<fit>.<param>`` (:func:`param_key`, :func:`split_param`). Everything
that turns a key back into a gear or a direction (the torque converter's transmission table, the
validation's expectations and gain scoring) goes through :meth:`FitKey.parse`.

============================  ==================================================================
``transmission.gear5``        ``FitKey("transmission", gear=5, direction="drive")``
``transmission.gear5_coast``  ``FitKey("transmission", gear=5, direction="coast")``
``shifts.up_1_2``             ``FitKey("shifts", gear=1, direction="up")`` (gear: the gear left)
``shifts.down_2_1``           ``FitKey("shifts", gear=2, direction="down")``
``motor.motoring``            ``FitKey("motor", "motoring")``
``battery``                   ``FitKey("battery")``
============================  ==================================================================
"""

from __future__ import annotations

import re
from dataclasses import dataclass

from benchtwin.errors import DataError

__all__ = ["FitKey", "param_key", "split_param"]

_TX = re.compile(r"^transmission\.gear(\d+)(_coast)?$")
_SHIFT = re.compile(r"^shifts\.(up|down)_(\d+)_(\d+)$")


@dataclass(frozen=True, order=True)
class FitKey:
    """The name of one fit.

    Attributes
    ----------
    subsystem:
        ``transmission``, ``motor``, ``engine``, ``shifts``, ...
    part:
        The fit within the subsystem (``motoring``, ``bsfc``, ``front``, ``converter``), if any.
    gear:
        Transmission: the gear; shifts: the gear the shift leaves.
    direction:
        Transmission: ``drive`` or ``coast``; shifts: ``up`` or ``down``.
    """

    subsystem: str
    part: str | None = None
    gear: int | None = None
    direction: str | None = None

    @classmethod
    def transmission(cls, gear: int, direction: str = "drive") -> FitKey:
        """The efficiency fit of one gear in ``drive`` or ``coast``."""
        if direction not in ("drive", "coast"):
            raise DataError(f"transmission direction {direction!r}: allowed are 'drive' and 'coast'")
        return cls("transmission", gear=int(gear), direction=direction)

    @classmethod
    def shift(cls, from_gear: int, direction: str) -> FitKey:
        """The shift line leaving ``from_gear`` ``up`` or ``down``."""
        if direction not in ("up", "down"):
            raise DataError(f"shift direction {direction!r}: allowed are 'up' and 'down'")
        return cls("shifts", gear=int(from_gear), direction=direction)

    @property
    def to_gear(self) -> int | None:
        """The gear a shift line leads to (None for other fits)."""
        if self.subsystem != "shifts" or self.gear is None:
            return None
        return self.gear + 1 if self.direction == "up" else self.gear - 1

    @property
    def local(self) -> str:
        """The name within the subsystem (``up_1_2``, ``gear5_coast``, ``motoring``; ``""`` for a whole one)."""
        return str(self).partition(".")[2]

    def __str__(self) -> str:
        if self.subsystem == "transmission" and self.gear is not None:
            return f"transmission.gear{self.gear}" + ("_coast" if self.direction == "coast" else "")
        if self.subsystem == "shifts" and self.gear is not None:
            return f"shifts.{self.direction}_{self.gear}_{self.to_gear}"
        return self.subsystem if self.part is None else f"{self.subsystem}.{self.part}"

    @classmethod
    def parse(cls, text: str) -> FitKey:
        """The key of a fit name (the inverse of ``str``)."""
        m = _TX.match(text)
        if m:
            return cls.transmission(int(m.group(1)), "coast" if m.group(2) else "drive")
        m = _SHIFT.match(text)
        if m:
            key = cls.shift(int(m.group(2)), m.group(1))
            if key.to_gear != int(m.group(3)):
                raise DataError(f"fit name {text!r}: a shift {m.group(1)} from gear {m.group(2)} leads to "
                                f"gear {key.to_gear}")
            return key
        subsystem, _, part = text.partition(".")
        if not subsystem:
            raise DataError(f"empty fit name {text!r}")
        return cls(subsystem, part or None)


def param_key(fit: FitKey | str, param: str) -> str:
    """``<fit>.<param>``, the key of a parameter in ``IdentificationResult.parameters()``."""
    return f"{fit}.{param}"


def split_param(key: str) -> tuple[FitKey, str]:
    """The fit and the parameter name of a parameter key (the inverse of :func:`param_key`)."""
    fit, _, param = key.rpartition(".")
    if not fit:
        raise DataError(f"parameter key {key!r} has no fit part")
    return FitKey.parse(fit), param
