"""Wire formats shared by the devices (sensors) and the acquisition (chain).

Nothing here knows the physics or the transports: the frame-table and register-snapshot types
(:mod:`~benchtwin.wire.frames`), the cantools messages of every CAN layout (:mod:`~benchtwin.wire.dbc`),
their compiled column codecs (:mod:`~benchtwin.wire.codec`), the CANopen thermo module's PDO layout from
its EDS (:mod:`~benchtwin.wire.canopen_pdo`), the Modbus register map (:mod:`~benchtwin.wire.modbus_map`)
and the k-way merge of time-sorted frame runs (:mod:`~benchtwin.wire.merge`). Both sides import these,
so an encoder and its decoder cannot disagree about a layout.
"""
