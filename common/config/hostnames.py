"""Where a process of hubs.toml runs and who deploys it: checked before they reach an ssh command line.

`host` is a hostname (RFC 1123 labels, optionally dotted) or an IP address literal; `ssh_user` a
POSIX portable user name (letters, digits, `.`, `_`, `-`, not starting with `-`, at most 32
characters). Anything else, `-oProxyCommand=...` above all, would be read by ssh as an option.
"""

from __future__ import annotations

import ipaddress
import re

_LABEL = r"(?!-)[A-Za-z0-9-]{1,63}(?<!-)"
HOSTNAME = re.compile(rf"{_LABEL}(\.{_LABEL})*\.?")
USER_NAME = re.compile(r"[A-Za-z0-9_.][A-Za-z0-9_.-]{0,31}")


def host_problem(host: str) -> str | None:
    """Why `host` is neither a hostname nor an IP literal, or None."""
    try:
        ipaddress.ip_address(host)
        return None
    except ValueError:
        pass
    if len(host) <= 253 and HOSTNAME.fullmatch(host) and not host.replace(".", "").isdigit():
        return None
    return f"{host!r} is neither a hostname (letters, digits, '-' and dots) nor an IP address"


def user_problem(user: str) -> str | None:
    """Why `user` is not a POSIX user name, or None."""
    if USER_NAME.fullmatch(user):
        return None
    return (f"{user!r} is not a user name (letters, digits, '.', '_' and '-', not starting with '-', "
            f"at most 32 characters)")
