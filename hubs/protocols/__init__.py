"""Protocol constants shared by a driver and its simulator: one module per protocol.

A driver (`hubs/drivers/`) and the simulator that stands in for its device
(`hubs/sim/`) both import their protocol's module here, so that a port, a register
address or a message id is written down once.
"""
