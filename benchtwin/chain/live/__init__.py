"""Live delivery and live acquisition: device outputs paced onto real transports, and recorded back.

- :mod:`.scheduler`: :class:`~.scheduler.LiveScheduler` paces :class:`~.scheduler.Stream` s in real time or
  at a speed-up, with pacing statistics and bus load.
- :mod:`.modbus_server`: the pressure module's Modbus TCP server (pymodbus) over a register store.
- :mod:`.canopen_node`: the thermo module as a canopen LocalNode, and the RemoteNode acquisition.
- :mod:`.ivt_commands`: the IVT-S command channel answered live.
- :mod:`.session`: everything of a run wired together (what ``benchtwin serve`` runs).
- :mod:`.recorder`: the live acquisition (what ``benchtwin record`` runs).
"""
