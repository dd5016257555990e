"""A private DDS domain for a graph that one command starts (``taiji2 experiment``).

Two graphs on one domain see each other's topics and clash on node names. A command that starts a
whole graph of its own therefore takes a domain no one else uses, unless the user chose one with
``ROS_DOMAIN_ID``. A domain is taken when

* no other process holds its lock file ``<temp dir>/taiji2-dds-domain-<id>.lock`` (an exclusive
  ``flock``, held until the process exits; other commands that pick a private domain skip it), and
* no DDS participant on this host uses it: none of the UDP ports of its first participant indices
  (``7410 + 250 id + 2 i`` and the next one, Cyclone DDS's and rmw_cyclonedds's port mapping, which
  the embedded runtime's loopback configuration uses) nor its discovery multicast port
  (``7400 + 250 id``) can be bound.

Candidates are :data:`PRIVATE_DOMAINS`, above the domains people choose by hand (0-101, ROS 2's
recommended range) and the test suite's (100-201); the search starts at an offset derived from
the process id, so two commands that start at once rarely probe the same domain first.
"""

from __future__ import annotations

import errno
import os
import socket
import tempfile
from pathlib import Path
from typing import IO

__all__ = ["PRIVATE_DOMAINS", "DomainReservation", "domain_in_use", "reserve_private_domain"]

#: domains a command picks from for a private graph (232 is the highest the port mapping allows)
PRIVATE_DOMAINS = range(202, 233)
#: participant indices probed per domain (the graph's own nodes take the first free ones)
_PROBED_INDICES = 4


class DomainReservation:
    """A domain id and the lock that keeps it ours; :meth:`release` (or process exit) frees it."""

    def __init__(self, domain_id: int, lock: IO[bytes] | None) -> None:
        self.domain_id = domain_id
        self._lock = lock

    def release(self) -> None:
        """Give the domain back (closing the lock file drops the flock)."""
        if self._lock is not None:
            self._lock.close()
            self._lock = None


def _ports(domain_id: int) -> list[int]:
    base = 7400 + 250 * domain_id
    ports = [base]  # SPDP multicast (ROS 2's default Cyclone configuration binds it)
    for index in range(_PROBED_INDICES):
        ports += [base + 10 + 2 * index, base + 11 + 2 * index]
    return ports


def domain_in_use(domain_id: int) -> bool:
    """True when a DDS participant on this host holds one of the domain's first ports."""
    for port in _ports(domain_id):
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
            try:
                probe.bind(("0.0.0.0", port))
            except OSError as exc:
                if exc.errno in (errno.EADDRINUSE, errno.EACCES):
                    return True
                raise
    return False


def _lock(domain_id: int, directory: Path) -> IO[bytes] | None:
    import fcntl

    path = directory / f"taiji2-dds-domain-{domain_id}.lock"
    try:
        handle = open(path, "ab")  # held open for the life of the reservation
    except OSError:
        try:  # another user's lock file: a shared lock on it is still a valid test of its holder
            handle = open(path, "rb")
        except OSError:
            return None
    try:
        fcntl.flock(handle.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        handle.close()
        return None
    return handle


def reserve_private_domain(candidates: range = PRIVATE_DOMAINS, directory: str | os.PathLike[str] | None = None,
                           ) -> DomainReservation:
    """Reserve a free domain of ``candidates`` (see the module doc).

    Raises
    ------
    RuntimeError
        If every candidate is in use (the message says how to choose one).
    """
    where = Path(directory or tempfile.gettempdir())
    start = os.getpid() % len(candidates)
    for k in range(len(candidates)):
        domain_id = candidates[(start + k) % len(candidates)]
        lock = _lock(domain_id, where)
        if lock is None:
            continue
        if domain_in_use(domain_id):
            lock.close()
            continue
        return DomainReservation(domain_id, lock)
    raise RuntimeError(f"no free DDS domain in {candidates.start}-{candidates.stop - 1} on this host; "
                       "set ROS_DOMAIN_ID to choose one")
