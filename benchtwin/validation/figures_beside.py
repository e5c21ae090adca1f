"""The report's figures drawn by the side stages' child (:mod:`benchtwin.validation.beside`), beside the type B re-runs.

The identification figures draw the fits (their data, estimates, R² and status), never a type B interval, and
the held-out drive's figure draws the prediction the child makes: so the child can draw them all from the nominal
identification result, which :func:`~benchtwin.identification.run.identify_all` hands out (``on_nominal``) before
its re-runs. The parent sends it (``"nominal"``, pickled as it is then), the child draws once its prediction no
longer needs the identification (before it waits for the tolerances) and sends ``"figures"``: the images, or the
exception a figure raised, which the parent raises where it would have drawn them (:func:`drawn_images`).
"""

from __future__ import annotations

from typing import Any

from benchtwin.config.specs import VehicleSpecs
from benchtwin.errors import packed_exception
from benchtwin.validation.beside import _rebuilt
from benchtwin.validation.report import ValidationReport

__all__ = ["FigureDrawer", "drawn_images"]

#: the message keys: the nominal identification result (parent -> child), the figures (child -> parent)
NOMINAL, FIGURES = "nominal", "figures"


class _Failed:
    """A figure's exception, as it travels (pickled where it can be, and its traceback's text)."""

    def __init__(self, packed: tuple[bytes | None, str]) -> None:
        self.packed = packed


class FigureDrawer:
    """The child's end: :meth:`draw` waits for the nominal result, draws the report's figures and sends them.

    Parameters
    ----------
    channel:
        The side stage's channel (``put``, ``get``).
    report:
        The child's report (its ``prediction`` is drawn as it is when :meth:`draw` is called).
    specs:
        Public specs (the motor's full-load curve).
    """

    def __init__(self, channel: Any, report: ValidationReport, specs: VehicleSpecs | None) -> None:
        self.channel, self.report, self.specs = channel, report, specs
        self.done = False

    def draw(self) -> None:
        """Draw and send the figures (once; a later call does nothing)."""
        if self.done:
            return
        self.done = True
        nominal = self.channel.get(NOMINAL)
        try:
            from benchtwin.validation.html import figure_images

            drawn: Any = figure_images(self.report.prediction, nominal, self.specs)
        except Exception as exc:  # raised by the parent where it draws in line
            drawn = _Failed(packed_exception(exc))
        self.channel.put(FIGURES, drawn)


def drawn_images(value: Any) -> tuple[list[tuple[str, bytes]], dict[str, str]]:
    """The figures the child sent, or its figure's exception raised.

    Parameters
    ----------
    value:
        What the child sent under ``"figures"``.

    Returns
    -------
    tuple
        (caption, PNG bytes) and figure stem -> why it was not drawn (as
        :func:`~benchtwin.validation.html.figure_images` gives them).
    """
    if isinstance(value, _Failed):
        raise _rebuilt(value.packed)
    return value
