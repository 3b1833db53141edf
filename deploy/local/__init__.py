"""The station on this machine: `hubctl up` as processes over loopback Zenoh (`station`), in one
process in virtual time (`inprocess`), the simulated world of `--mode sim` (`simworld`)."""
