"""`taiji2 experiment` runs its graph on a private DDS domain unless ROS_DOMAIN_ID is set (issue 27)."""

from __future__ import annotations

import os
import socket

import pytest

from taiji2_runtime.domain import DomainReservation, domain_in_use, reserve_private_domain


def test_two_reservations_never_share_a_domain(tmp_path):
    free = [d for d in range(202, 233) if not domain_in_use(d)][:4]
    candidates = range(free[0], free[0] + 1) if len(free) < 2 else range(min(free), max(free) + 1)
    first = reserve_private_domain(candidates, tmp_path)
    second = reserve_private_domain(candidates, tmp_path) if len(candidates) > 1 else None
    try:
        assert second is None or first.domain_id != second.domain_id
    finally:
        first.release()
        if second is not None:
            second.release()
    only = range(first.domain_id, first.domain_id + 1)
    held = reserve_private_domain(only, tmp_path)  # released above: free again
    try:
        with pytest.raises(RuntimeError):  # the lock alone keeps a domain while another command holds it
            reserve_private_domain(only, tmp_path)
    finally:
        held.release()


def test_a_domain_with_a_participant_on_this_host_is_skipped(tmp_path):
    # two neighbouring domains nobody uses now; a DDS participant of the first holds its unicast
    # discovery port (participant index 0)
    busy = next(d for d in range(202, 232) if not domain_in_use(d) and not domain_in_use(d + 1))
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as participant:
        participant.bind(("0.0.0.0", 7400 + 250 * busy + 10))
        assert domain_in_use(busy)
        reservation = reserve_private_domain(range(busy, busy + 2), tmp_path)
        assert reservation.domain_id == busy + 1
        reservation.release()
        with pytest.raises(RuntimeError, match="set ROS_DOMAIN_ID"):
            reserve_private_domain(range(busy, busy + 1), tmp_path)


def test_an_explicit_ros_domain_id_is_kept(monkeypatch):
    from taiji2_apps.cli.experiment import _private_domain

    monkeypatch.setenv("ROS_DOMAIN_ID", "97")
    assert _private_domain() is None and os.environ["ROS_DOMAIN_ID"] == "97"
    monkeypatch.delenv("ROS_DOMAIN_ID")
    reservation = _private_domain()
    try:
        assert isinstance(reservation, DomainReservation)
        assert os.environ["ROS_DOMAIN_ID"] == str(reservation.domain_id) and reservation.domain_id >= 202
    finally:
        reservation.release()
