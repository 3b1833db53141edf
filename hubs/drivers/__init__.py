"""Device drivers: one module per device protocol, behind the contract of `base.py`.

* `base`: `Driver` (connect, read, write, enter_safe_state, selftest) and the declared
  capabilities `Inputs` and `Observes`.
* `registry`: which driver serves a device type (`find_driver`): the built-in table,
  then installed plugins (entry-point group `statehub.drivers`). Each driver module
  exports `PLUGIN`, a `DriverPlugin` of its parameter Struct and its build function.
* `params`: the parameters every driver takes and the typed conversion of a device's
  hubs.toml table, with errors that name the parameter.
* `reconnect`, `modbus_io`: the one reconnect loop, and the Modbus link two drivers share.

Driver modules are imported on demand, so a hub only loads the libraries its devices
use. Drivers never import simulators: `hubs.factory` builds a driver for sim mode
through the simulator registry (`hubs.sim.registry`). See docs/drivers.md.
"""
