"""sd_notify(3) without libsystemd: one datagram to $NOTIFY_SOCKET per message.

systemd's notify protocol is a newline-separated "KEY=VALUE" datagram sent to the AF_UNIX
socket named by $NOTIFY_SOCKET (a leading '@' means the Linux abstract namespace). Outside
systemd the variable is unset and every call is a cheap no-op, so the daemon runs the same
code in a terminal, in tests and under `systemctl --user`.
"""

from __future__ import annotations

import logging
import os
import socket
from collections.abc import Mapping

log = logging.getLogger(__name__)


def notify_socket_address(env: Mapping[str, str]) -> str | bytes | None:
    """The address to send to, or None when not run by systemd (or the socket is unusable)."""
    name = env.get("NOTIFY_SOCKET", "")
    if name.startswith("@"):
        return b"\0" + name[1:].encode()  # abstract namespace: leading NUL byte, no file
    if name.startswith("/"):
        return name
    return None  # unset, or a vsock:... address this daemon never gets under a user unit


def watchdog_interval(env: Mapping[str, str], pid: int | None = None) -> float | None:
    """Seconds between WATCHDOG=1 pings (half of WATCHDOG_USEC), or None when not asked.

    systemd sets WATCHDOG_PID too; a ping is only expected from that process (a child that
    inherited the environment must not ping on its parent's behalf).
    """
    usec = env.get("WATCHDOG_USEC", "")
    if not usec.isdigit() or int(usec) == 0:
        return None
    owner = env.get("WATCHDOG_PID", "")
    if owner and owner.isdigit() and int(owner) != (os.getpid() if pid is None else pid):
        return None
    return int(usec) / 1_000_000 / 2


MUST_ARRIVE_S = 2.0  # READY= and STOPPING= wait this long for room in a full receiver queue


class SystemdNotifier:
    """Sends READY/STATUS/WATCHDOG/STOPPING; never raises (a lost datagram must not stop work)."""

    def __init__(self, env: Mapping[str, str] | None = None) -> None:
        env = os.environ if env is None else env
        self.address = notify_socket_address(env)
        self.watchdog_interval = watchdog_interval(env)

    @property
    def enabled(self) -> bool:
        return self.address is not None

    def send(self, *fields: str, wait_s: float = 0.0) -> bool:
        """wait_s: how long a full receiver queue may hold this message up (0: dropped at once)."""
        if self.address is None:
            return False
        message = "\n".join(fields).encode()
        try:
            # Non-blocking: a receiver that stopped reading (its queue holds ~10 datagrams)
            # must never stall the daemon's main loop; a lost STATUS= is harmless. READY= and
            # STOPPING= wait a moment: systemd fails a start whose READY=1 never came.
            with socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM | socket.SOCK_CLOEXEC) as sock:
                if wait_s > 0:  # connected: a wait for the peer's queue, not a spin
                    sock.settimeout(wait_s)
                    sock.connect(self.address)
                    sock.send(message)
                else:
                    sock.setblocking(False)
                    sock.sendto(message, self.address)
        except (BlockingIOError, TimeoutError):
            log.debug("sd_notify dropped: receiver queue full", extra={"fields": fields})
            return False
        except OSError as exc:
            log.warning("sd_notify failed: %s", exc, extra={"error": str(exc)})
            return False
        return True

    def ready(self, status: str = "") -> bool:
        return self.send("READY=1", *([f"STATUS={status}"] if status else []), wait_s=MUST_ARRIVE_S)

    def status(self, text: str) -> bool:
        return self.send(f"STATUS={text}")

    def watchdog(self) -> bool:
        return self.send("WATCHDOG=1")

    def stopping(self, status: str = "") -> bool:
        return self.send("STOPPING=1", *([f"STATUS={status}"] if status else []), wait_s=MUST_ARRIVE_S)
