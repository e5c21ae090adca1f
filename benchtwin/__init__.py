"""benchtwin: a hardware-in-the-loop test-bench emulator and sensor-chain validator.

A physics emulator of a P2 diesel plug-in hybrid on a chassis dyno drives the instruments of a
test bench (IVT-S shunts, SPA100 pressure transducers, a propeller-shaft strain gauge with
telemetry, type K thermocouples, vehicle CAN); the readings travel over real transports, an
acquisition decodes them into a :class:`~benchtwin.recording.Recording`, and the identification
methods of the reverse-engineering paper recover the powertrain parameters from it.
"""

from benchtwin.errors import BenchtwinError

__version__ = "0.1.0"
__all__ = ["BenchtwinError", "__version__"]
