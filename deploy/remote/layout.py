"""Where statehub lives on a target machine (an ECU or the controller PC).

    /opt/statehub/releases/<version>-<hash>/     one immutable release, shared by every process of the host
        venv/                                   the virtualenv with the statehub wheel installed
        hubs.toml                               the station file it was deployed with
        units/<unit>.service                    the systemd unit of each process deployed from it
        release.json                            what, when and by whom
        .complete                               written last: a release without it is discarded and rebuilt
    /opt/statehub/hubs/<hub>/current  ->  a release   what the hub's unit runs (switched atomically)
    /opt/statehub/controller/current  ->  a release   likewise for the controller
    /opt/statehub/hubs/<hub>/certs/, controller/certs/  ca.crt, NAME.crt, NAME.key (0600, tls mode only)
    /opt/statehub/releases.log                   one JSON line per deploy, rollback and revert
    /etc/systemd/system/statehub-hub-<hub>.service, statehub-controller.service

One `current` link per process, not per host, because several processes can share a
host (the reference station runs the controller and two hubs on `decs`): deploying one
hub must not change the code another one runs at its next restart.

`root` prefixes every path (`--root /tmp/x` puts the tree under /tmp/x), for tests and
for staging an image; users, groups and systemctl still act on the machine itself.
"""

from __future__ import annotations

import posixpath
from dataclasses import dataclass

BASE = "/opt/statehub"
UNIT_DIR = "/etc/systemd/system"
CONTROLLER = "controller"  # the process name of the controller (hubs are "hub:<name>" below)


def hub_unit_name(hub: str) -> str:
    return f"statehub-hub-{hub}.service"


CONTROLLER_UNIT = "statehub-controller.service"


@dataclass(frozen=True)
class Layout:
    root: str = "/"

    def path(self, absolute: str) -> str:
        """`absolute` under the root prefix."""
        if self.root in ("", "/"):
            return absolute
        return posixpath.join(self.root.rstrip("/"), absolute.lstrip("/"))

    @property
    def base(self) -> str:
        return self.path(BASE)

    @property
    def releases(self) -> str:
        return posixpath.join(self.base, "releases")

    @property
    def release_log(self) -> str:
        return posixpath.join(self.base, "releases.log")

    @property
    def unit_dir(self) -> str:
        return self.path(UNIT_DIR)

    def release(self, release_id: str) -> str:
        return posixpath.join(self.releases, release_id)

    def process_dir(self, hub: str | None) -> str:
        """The directory holding `current` of a hub, or of the controller for hub=None."""
        return posixpath.join(self.base, CONTROLLER) if hub is None else posixpath.join(self.base, "hubs", hub)

    def current(self, hub: str | None) -> str:
        return posixpath.join(self.process_dir(hub), "current")

    def certs(self, hub: str | None) -> str:
        """The process's certificate directory ([security] mode "tls"): kept across releases, 0700."""
        return posixpath.join(self.process_dir(hub), "certs")

    def unit_path(self, unit: str) -> str:
        return posixpath.join(self.unit_dir, unit)
