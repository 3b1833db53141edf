"""hubctl and what it drives.

* `cli`: hubctl's command line (the commands of the subpackages register themselves);
* `local/`: the station on this machine: `hubctl up` as processes or in one process, the simulated world;
* `remote/`: the station on its machines: systemd units, wheel, `hubctl deploy` and `rollback` over SSH;
* `modeltest/`: `hubctl test`, model-based tests of a running hub.
"""
