"""pick_cell: an example statehub station packaged on its own (model, driver, simulator, hubs.toml).

`model` the station model, `driver` the vacuum ejector's Modbus TCP driver, `sim` its
protocol simulator; both are registered as entry points in pyproject.toml.
"""
