"""The space-link model (contacts, light time, rate, memory, loss, duplicates) and ground reception (no DDS)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from taiji2_ground_pkg.reception import GroundReception
from taiji2_runtime.packets.definition import STREAMS
from taiji2_runtime.packets.packetize import encode_packet
from taiji2_sim_pkg.core.link import Downlink, LinkError, Uplink, load_link_model

DT = 0.1


def _packets(n_steps, streams=STREAMS[:3], t0=0.1):
    """(t_s, apid, packet) of ``n_steps`` samples of each stream, in generation order."""
    out = []
    for k in range(n_steps):
        t = t0 + k * DT
        for s in streams:
            out.append((t, s.apid, encode_packet(s, k, round(t * 1e9), np.full(len(s.fields), float(k)))))
    return out


def _run(model, packets, seed=0, chunk=10):
    link = Downlink(model, seed)
    deliveries = []
    for j in range(0, len(packets), chunk):
        part = packets[j:j + chunk]
        for t, apid, p in part:
            link.offer(t, apid, p)
        deliveries += link.advance(part[-1][0])
    deliveries += link.drain()
    return link, deliveries


def _model(**kw):
    base = {"light_time_s": 10.0, "contacts": {"windows": [[0.0, 30.0], [100.0, 400.0]]},
            "downlink_rate_bps": 64 * 8 * 3 * 20.0, "packet_overhead_octets": 0}
    return load_link_model({**base, **kw})


def test_presets_load_and_ideal_passes_everything_at_once():
    ideal = load_link_model("ideal")
    deep = load_link_model("deep_space")
    assert ideal.is_ideal and not deep.is_ideal
    assert 150 < deep.light_time_s < 600 and deep.contacts.period_s == 86400.0
    assert deep.random_loss_probability == 0.01 and abs(deep.burst_loss_fraction - 0.01) < 1e-3
    packets = _packets(200)
    _link, got = _run(ideal, packets)
    assert [d.packet for d in got] == [p for _, _, p in packets]
    assert all(d.receive_s == d.generated_s for d in got)
    with pytest.raises(LinkError, match="random_loss_probability"):
        load_link_model({"random_loss_probability": 2})
    with pytest.raises(LinkError, match="unknown key"):
        load_link_model({"light_time": 3})


def test_contacts_light_time_rate_and_playback_order():
    """Windows at 0-30 s and 100-400 s (ground), light time 10 s: the spacecraft sends during -10..20 s
    and 90..390 s; data of 20..90 s are stored and played back after the real-time data of the second pass."""
    model = _model()
    packets = _packets(1200)  # 0.1 .. 120 s
    link, got = _run(model, packets)
    receive = np.array([d.receive_s for d in got])
    generated = np.array([d.generated_s for d in got])
    assert np.all(np.diff(receive) >= 0)
    assert all(a <= r < b for r in receive for a, b in [next(w for w in [(0, 30), (100, 400)] if w[0] <= r < w[1])])
    assert np.all(receive - generated >= model.light_time_s - 1e-9)
    assert len(got) == len(packets) and not link.stored_at_end  # nothing lost: every packet arrives once
    stored = (generated >= 20.0) & (generated < 90.0)
    realtime_second_pass = generated >= 90.0
    first_rt = np.argmax(realtime_second_pass)
    assert np.any(stored[first_rt:])  # played back after real-time data began: out of time order
    # the rate: the transmitter never sends more than rate x time
    octets = np.array([len(d.packet) for d in got])
    in_second = receive >= 100
    span = receive[in_second][-1] - 100.0
    assert octets[in_second].sum() * 8 <= model.downlink_rate_bps * span + 8 * 120
    stats = link.stats[STREAMS[1].apid]
    assert stats.generated == 1200 and stats.delivered == 1200 and stats.reordered > 0 and stats.lost == 0
    # in real time: behind the star-tracker packet of the same sample, then its own transmission
    assert min(stats.latency_s) == pytest.approx(10.0 + (120 + 64) * 8 / model.downlink_rate_bps, abs=1e-6)
    # the ground puts everything back in order, without a gap
    rx = GroundReception()
    released = []
    for d in got:
        rx.offer(d.packet, round(d.receive_s * 1e9))
        released += rx.release(round(d.transmitted_through_s * 1e9))
    released += rx.finish()
    for s in STREAMS[:3]:
        t = [r.sample.onboard_ns for r in released if r.sample.stream is s]
        assert len(t) == 1200 and np.all(np.diff(t) > 0)
    assert all(c["missing"] == 0 and c["duplicate"] == 0 and c["out_of_order"] > 0 for c in rx.counts().values())


def test_memory_full_overwrites_oldest_and_counts():
    model = _model(storage_capacity_octets=64 * 3 * 100, faults={"missed_contacts": [1]},
                   contacts={"windows": [[0.0, 5.0], [50.0, 60.0], [200.0, 400.0]]})
    packets = _packets(1000)
    link, got = _run(model, packets)
    overwritten = sum(s.overwritten for s in link.stats.values())
    delivered = sum(s.delivered for s in link.stats.values())
    assert overwritten > 0 and overwritten + delivered == len(packets)
    assert link.overwrite_started_s is not None
    # what survives is the newest data
    kept = sorted({d.generated_s for d in got})
    assert kept[-1] == pytest.approx(100.0) and 1 not in link.contacts_used


def test_loss_and_duplicates_deterministic_with_rate_as_configured():
    model = load_link_model({"random_loss_probability": 0.01, "duplicate_probability": 0.01,
                             "burst_loss": {"p_good_to_bad": 0.00101, "p_bad_to_good": 0.1}})
    packets = _packets(20000, streams=STREAMS[1:2])
    a, got_a = _run(model, packets, seed=3, chunk=100)
    _b, got_b = _run(model, packets, seed=3, chunk=37)  # other batching: the same result
    assert [(d.receive_s, d.packet) for d in got_a] == [(d.receive_s, d.packet) for d in got_b]
    s = a.stats[STREAMS[1].apid]
    n = 20000
    expected = 1 - (1 - 0.01) * (1 - model.burst_loss_fraction)
    # bursts of mean 10 packets: the loss count's std ~ sqrt(n p 10) ~ 63; 5 sigma
    assert abs(s.lost - n * expected) < 5 * math.sqrt(n * expected * 10)
    assert abs(s.duplicated - 0.01 * s.delivered) < 5 * math.sqrt(0.01 * s.delivered)
    rx = GroundReception()
    for d in got_a:
        rx.offer(d.packet, round(d.receive_s * 1e9))
    rx.release(round(got_a[-1].transmitted_through_s * 1e9))
    rx.finish()
    c = rx.counts()["grs1"]
    k = sorted({int(d.generated_s / DT + 0.5) for d in got_a})  # the samples that arrived
    assert c["duplicate"] == s.duplicated and c["released"] == s.delivered == len(k)
    assert c["missing"] == (k[-1] - k[0] + 1) - len(k) and c["held"] == 0  # every gap between them declared


def test_uplink_in_passes_with_light_time_and_faults():
    model = _model(uplink_rate_bps=800.0, faults={"lost_uplinks": [1]})
    up = Uplink(model)
    a = up.send(-50.0, b"x" * 100)  # waits for the first pass; 1 s at 800 bit/s
    assert a.contact == 0 and a.sent_s == 0.0 and a.arrival_s == pytest.approx(11.0) and not a.lost
    b = up.send(29.5, b"x" * 100)  # does not fit in the first pass: the second, where the uplink is lost
    assert b.contact == 1 and b.sent_s == 100.0 and b.lost and "fault" in b.reason
    assert up.send(500.0, b"x") is None  # no pass left
