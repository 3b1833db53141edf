"""The shell scripts `hubctl deploy` and `hubctl rollback` run on a target, as plain text.

POSIX sh plus GNU coreutils (`mv -T`), as on Raspberry Pi OS and Debian. Every script is
safe to run again: a release is complete only once `.complete` exists (a half-built one
is discarded and rebuilt), the unit and `current` are replaced by rename, never edited
in place. Every interpolated value goes through shlex.quote.
"""

from __future__ import annotations

import json
import posixpath
import shlex
from collections.abc import Mapping
from dataclasses import dataclass

from .layout import Layout

q = shlex.quote
MIN_PYTHON = (3, 11)
SERVICE_USER = "statehub"


# --- probe -----------------------------------------------------------------------------------

def probe(layout: Layout, hub: str | None, release: str, python: str) -> str:
    return f"""set -u
echo "uid=$(id -u)"
PY={q(python)}
if command -v "$PY" >/dev/null 2>&1; then
  "$PY" - <<'EOF'
import importlib.util as u, sys
print("python=%d.%d.%d" % sys.version_info[:3])
print("ensurepip=" + ("yes" if u.find_spec("venv") and u.find_spec("ensurepip") else "no"))
print("pip=" + ("yes" if u.find_spec("pip") else "no"))
EOF
else
  echo python=
fi
if [ "$(id -u)" != 0 ]; then sudo -n true >/dev/null 2>&1 && echo sudo=yes || echo sudo=no; fi
echo "systemd=$(systemctl --version 2>/dev/null | head -n 1)"
echo "current=$(readlink {q(layout.current(hub))} 2>/dev/null)"
REL={q(layout.release(release))}
if [ -f "$REL/.complete" ]; then echo release=complete; elif [ -e "$REL" ]; then echo release=partial; \
else echo release=none; fi
"""


@dataclass(frozen=True)
class Probe:
    uid: int
    python: tuple[int, ...] | None
    ensurepip: bool
    pip: bool
    systemd: str  # first line of `systemctl --version`, "" when there is none
    current: str | None  # the release `current` points at (its directory name)
    release: str  # "complete" | "partial" | "none": the state of the release being deployed
    sudo: bool = False  # the (non-root) user may sudo without a password


def parse_probe(stdout: str) -> Probe:
    values = dict(line.split("=", 1) for line in stdout.splitlines() if "=" in line)
    version = values.get("python", "")
    current = values.get("current", "").rstrip("/")
    return Probe(
        uid=int(values.get("uid", "-1") or -1),
        python=tuple(int(p) for p in version.split(".")) if version else None,
        ensurepip=values.get("ensurepip") == "yes",
        pip=values.get("pip") == "yes",
        systemd=values.get("systemd", ""),
        current=posixpath.basename(current) if current else None,
        release=values.get("release", "none"),
        sudo=values.get("sudo") == "yes",
    )


# --- release ---------------------------------------------------------------------------------

# Two deploys to one host (several hubs can share it) may build the same release: they
# take turns, and the second finds the first's work done. flock is in util-linux.
_LOCK = """mkdir -p "$(dirname "$REL")"
exec 9>"$(dirname "$REL")/.lock"
flock 9
"""

def upload() -> str:
    """Unpack a tar stream from stdin into a fresh staging directory; print its path."""
    return """set -eu
STAGE=$(mktemp -d /tmp/statehub-deploy.XXXXXX)
tar -x -C "$STAGE" -f -
echo "$STAGE"
"""


def cleanup(stage: str) -> str:
    return f"rm -rf {q(stage)}\n"


def create_venv(layout: Layout, release: str, python: str, *, system_site_packages: bool, without_pip: bool) -> str:
    flags = "".join(f" {f}" for f, on in (("--system-site-packages", system_site_packages),
                                          ("--without-pip", without_pip)) if on)
    rel = q(layout.release(release))
    return f"""set -eu
REL={rel}
{_LOCK}if [ -f "$REL/.complete" ]; then echo "reused $REL"; exit 0; fi
if [ -f "$REL/.venv-ok" ]; then echo "reused the venv of an unfinished deploy in $REL"; exit 0; fi
rm -rf "$REL"
mkdir -p "$REL"
{q(python)} -m venv{flags} "$REL/venv"
touch "$REL/.venv-ok"
echo "created $REL/venv"
"""


def install(layout: Layout, release: str, stage: str, wheel: str, *, offline_deps: bool,
            metadata: Mapping[str, object]) -> str:
    rel = q(layout.release(release))
    # offline: the dependencies come from the interpreter's own site-packages (the venv sees them).
    pip_flags = " --no-deps --no-index" if offline_deps else ""
    return f"""set -eu
REL={rel}
STAGE={q(stage)}
WHEEL={q(wheel)}
{_LOCK}if [ -f "$REL/.complete" ]; then echo "reused $REL"; exit 0; fi
"$REL/venv/bin/python" -m pip install --quiet --disable-pip-version-check --no-input{pip_flags} "$STAGE/$WHEEL"
cp "$STAGE/$WHEEL" "$REL/"
cp "$STAGE/hubs.toml" "$REL/hubs.toml"
printf '%s\\n' {q(json.dumps(metadata, sort_keys=True))} > "$REL/release.json"
chmod -R a+rX "$REL"
chmod 0600 "$REL/hubs.toml"  # it holds device passwords (the MiR's): the service user's alone (install_unit)
touch "$REL/.complete"
echo "installed {wheel}"
"""


def install_unit(layout: Layout, release: str, stage: str, unit: str, groups: list[str], *,
                 certs: tuple[str, list[str]] | None = None) -> str:
    """Create the service user and device groups if missing, install the unit, reload, enable;
    the staging directory is not needed after this. `certs`: (directory, staged file names) of the
    process's certificate and key, installed readable by the service user only."""
    rel, unit_dir = q(layout.release(release)), q(layout.unit_dir)
    group_lines = "".join(f'getent group {q(g)} >/dev/null || groupadd --system {q(g)}\n' for g in groups)
    owner = f"-o {SERVICE_USER} -g {SERVICE_USER}"
    cert_lines = "" if certs is None else f"install -d -m 0700 {owner} {q(certs[0])}\n" + "".join(
        f"install -m 0600 {owner} {q(stage)}/{q(n)} {q(certs[0])}/{q(n)}\n" for n in certs[1])
    return f"""set -eu
{group_lines}if ! id -u {SERVICE_USER} >/dev/null 2>&1; then
  useradd --system --user-group --no-create-home --home-dir /nonexistent --shell /usr/sbin/nologin {SERVICE_USER}
fi
chown {SERVICE_USER}:{SERVICE_USER} {rel}/hubs.toml
chmod 0600 {rel}/hubs.toml
{cert_lines}mkdir -p {rel}/units {unit_dir}
cp {q(stage)}/{q(unit)} {rel}/units/{q(unit)}
cp {q(stage)}/{q(unit)} {unit_dir}/.{q(unit)}.new
mv -f {unit_dir}/.{q(unit)}.new {unit_dir}/{q(unit)}
systemctl daemon-reload
systemctl enable --quiet {q(unit)}
rm -rf {q(stage)}
"""


# --- switching ---------------------------------------------------------------------------------

def log_line(*, hub: str, action: str, release: str | None, previous: str | None, by: str, time: str) -> str:
    return json.dumps({"time": time, "hub": hub, "action": action, "release": release, "previous": previous,
                       "by": by}, sort_keys=True)


def _switch_body(layout: Layout, hub: str | None, release: str, log: str) -> str:
    proc = q(layout.process_dir(hub))
    # The log line goes first: should the rename fail, a line naming a release that never
    # became current misleads nobody (rollback follows the deploys of the current release).
    return f"""mkdir -p {proc}
printf '%s\\n' {q(log)} >> {q(layout.release_log)}
ln -sfn {q(layout.release(release))} {proc}/.current.new
mv -T {proc}/.current.new {proc}/current
"""


def switch(layout: Layout, hub: str | None, release: str, log: str) -> str:
    """Point `current` at the release atomically (a new link renamed over the old), then log it."""
    return "set -eu\n" + _switch_body(layout, hub, release, log)


def restart(unit: str) -> str:
    return f"systemctl restart {q(unit)}\n"


def activate(layout: Layout, hub: str | None, release: str, unit: str, log: str) -> str:
    """Rollback: switch `current` to an existing release and put its unit back in place."""
    rel, unit_dir = q(layout.release(release)), q(layout.unit_dir)
    return f"""set -eu
if [ ! -f {rel}/.complete ]; then echo "release {release} is incomplete" >&2; exit 1; fi
if [ ! -f {rel}/units/{q(unit)} ]; then echo "release {release} has no unit {unit}" >&2; exit 1; fi
cp {rel}/units/{q(unit)} {unit_dir}/.{q(unit)}.new
mv -f {unit_dir}/.{q(unit)}.new {unit_dir}/{q(unit)}
systemctl daemon-reload
{_switch_body(layout, hub, release, log)}"""


def revert(layout: Layout, hub: str | None, unit: str, previous: str | None, *, switched: bool, log: str) -> str:
    """Undo a failed deploy: the previous release's unit, `current` and process again; with no
    previous release, no unit at all (a unit left enabled would restart-loop at every boot)."""
    unit_dir, proc = q(layout.unit_dir), q(layout.process_dir(hub))
    if previous is None:
        return f"""set -u
systemctl disable --now --quiet {q(unit)}
rm -f {proc}/current {unit_dir}/{q(unit)}
systemctl daemon-reload
"""
    prev = q(layout.release(previous))
    lines = ["set -eu",
             f"if [ -f {prev}/units/{q(unit)} ]; then",
             f"  cp {prev}/units/{q(unit)} {unit_dir}/.{q(unit)}.new",
             f"  mv -f {unit_dir}/.{q(unit)}.new {unit_dir}/{q(unit)}",
             "fi",
             "systemctl daemon-reload"]
    if switched:
        lines += [f"ln -sfn {prev} {proc}/.current.new",
                  f"mv -T {proc}/.current.new {proc}/current",
                  f"printf '%s\\n' {q(log)} >> {q(layout.release_log)}",
                  f"systemctl restart {q(unit)}"]
    return "\n".join(lines) + "\n"


def read_log(layout: Layout, hub: str | None) -> str:
    """uid, current release and the complete releases, then `---` and the release log."""
    return f"""set -u
echo "uid=$(id -u)"
echo "current=$(basename "$(readlink {q(layout.current(hub))} 2>/dev/null)" 2>/dev/null)"
for r in {q(layout.releases)}/*/.complete; do [ -f "$r" ] && echo "release=$(basename "$(dirname "$r")")"; done
echo ---
cat {q(layout.release_log)} 2>/dev/null || true
"""


@dataclass(frozen=True)
class History:
    uid: int
    current: str | None
    releases: list[str]  # the complete releases on the target
    log: str


def parse_history(stdout: str) -> History:
    head, _, log = stdout.partition("---\n")
    uid, current, releases = -1, None, []
    for line in head.splitlines():
        key, _, value = line.partition("=")
        if key == "uid" and value.lstrip("-").isdigit():
            uid = int(value)
        elif key == "current" and value:
            current = value
        elif key == "release" and value:
            releases.append(value)
    return History(uid, current, sorted(releases), log)


def previous_release(log_text: str, hub: str, current: str | None) -> str | None:
    """The release that was current before `current` was deployed: the `previous` of the
    newest deploy of `current` (so repeated rollbacks walk back through the deploys)."""
    entries = []
    for line in log_text.splitlines():
        try:
            entry = json.loads(line)
        except ValueError:
            continue  # a torn line (a full disk, a power cut) must not block a rollback
        if isinstance(entry, dict) and entry.get("hub") == hub:
            entries.append(entry)
    for entry in reversed(entries):
        if entry.get("action") == "deploy" and entry.get("release") == current:
            previous = entry.get("previous")
            return previous if isinstance(previous, str) else None
    return None
