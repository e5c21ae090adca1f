"""The benchtwin exception tree.

Every error the project raises derives from :class:`BenchtwinError` and also from the built-in
exception that matches its meaning, so callers may catch either::

    BenchtwinError
     ├── ConfigError (ValueError)               a scenario file is wrong: names file, key, value, fix
     ├── DataError (ValueError)                 a Trace, Recording or log holds unusable data
     │    └── MissingChannelError (LookupError) a channel or role that is needed is absent
     ├── SimulationError (RuntimeError)         the plant cannot go on (e.g. solver left its domain)
     ├── ProtocolError (ValueError)             bytes on a wire are wrong; carries ``code``
     │    ├── FrameError                        malformed CAN frame (DLC, mux byte, unknown id)
     │    ├── ModbusExceptionError              a Modbus exception response (``code`` = spec code)
     │    └── CanopenError                      an SDO abort or PDO mapping problem (``code``)
     ├── TransportError (ConnectionError)       a bus, socket or server failed or dropped
     │    └── TransportTimeoutError (TimeoutError)
     └── IdentificationError (ValueError)       identification cannot give trustworthy numbers
          ├── InsufficientDataError             too few usable points
          ├── NoExcitationError                 the regressors do not vary enough
          ├── CollinearError                    the regressors are (nearly) linearly dependent
          └── FitFailedError (RuntimeError)     the optimiser did not converge

No ``assert`` is used for validation anywhere in the package.
"""

from __future__ import annotations

import pickle
import traceback

__all__ = [
    "BenchtwinError",
    "CanopenError",
    "CollinearError",
    "ConfigError",
    "DataError",
    "FitFailedError",
    "FrameError",
    "IdentificationError",
    "InsufficientDataError",
    "MissingChannelError",
    "ModbusExceptionError",
    "NoExcitationError",
    "ProtocolError",
    "SimulationError",
    "TransportError",
    "TransportTimeoutError",
    "packed_exception",
]


class BenchtwinError(Exception):
    """Root of every error raised by benchtwin."""


class ConfigError(BenchtwinError, ValueError):
    """A scenario file (vehicle, setup, campaign, signal map) is invalid.

    The message is one line per problem: ``FILE: key 'a.b' = VALUE: what is allowed``.
    """


class DataError(BenchtwinError, ValueError):
    """A Trace, Recording or log file holds data that cannot be used as asked."""


class MissingChannelError(DataError, LookupError):
    """A channel or signal role needed for an operation is not present."""


class SimulationError(BenchtwinError, RuntimeError):
    """The emulator cannot continue (invalid state or protocol)."""


class ProtocolError(BenchtwinError, ValueError):
    """Bytes on a wire do not follow the protocol.

    Parameters
    ----------
    message:
        Human-readable description.
    code:
        The protocol's own code where it has one (Modbus exception code, SDO abort code,
        IVT-S status nibble), else ``None``.
    """

    def __init__(self, message: str, code: int | None = None) -> None:
        super().__init__(message)
        self.code = code


class FrameError(ProtocolError):
    """A malformed CAN frame: wrong DLC, bad mux byte, unknown identifier."""


class ModbusExceptionError(ProtocolError):
    """A Modbus exception response; ``code`` is the Modbus exception code (1..11)."""


class CanopenError(ProtocolError):
    """A CANopen SDO abort or PDO problem; ``code`` is the SDO abort code where known."""


class TransportError(BenchtwinError, ConnectionError):
    """A transport (CAN bus, TCP endpoint, Modbus or CANopen link) failed or dropped."""


class TransportTimeoutError(TransportError, TimeoutError):
    """A transport did not answer within its timeout."""


class IdentificationError(BenchtwinError, ValueError):
    """Identification cannot produce trustworthy numbers from the data given."""


class InsufficientDataError(IdentificationError):
    """Too few usable points (after excluding clipped or flagged samples)."""


class NoExcitationError(IdentificationError):
    """The data do not excite the model: a regressor barely varies."""


class CollinearError(IdentificationError):
    """The regressors are (nearly) linearly dependent; the parameters are not separable."""


class FitFailedError(IdentificationError, RuntimeError):
    """An iterative fit did not converge."""


def packed_exception(exc: BaseException) -> tuple[bytes | None, str]:
    """``exc`` for another process: pickled (None where it does not pickle back) and its traceback's text.

    The forked stages (the chain's producer, the side stages) send a failure this way; the receiving side raises the
    same exception with the text as a note, or an error of its own with the text where it did not pickle.
    """
    text = "".join(traceback.format_exception(exc))
    try:
        data: bytes | None = pickle.dumps(exc)
        pickle.loads(data)
    except Exception:  # an exception that does not survive pickling travels as text
        data = None
    return data, text
