"""The station on its machines: the release layout on a target (`layout`), the systemd units (`units`),
the wheel (`wheel`), the target-side scripts (`scripts`), OpenSSH (`ssh`), `hubctl deploy` and `rollback`
with their numbered steps (`progress`) and the wait for a restarted hub (`hubwait`); `cli` registers the
commands."""
