"""The switch benchmark's accounting: payload heads found across split reads, each delivery counted once."""

from __future__ import annotations

from entitynet import protocol as P
from sims.bench.switch_drivers import PAD, PAYLOAD, NatsDriver, OursDriver, RedisDriver, _resp
from sims.bench.switch_readers import Scanner, Tally


def _ours_stream(recs) -> bytes:
    msgs = [P.encode_message(P.Update(2**40 + e, s, (1, 2), 500, PAYLOAD.pack(t, e, s) + PAD, None))
            for t, e, s in recs]
    return P.frame(P.payload_from_encoded(msgs))


def _redis_stream(recs) -> bytes:
    return b"".join(_resp(b"message", b"c7", PAYLOAD.pack(t, e, s) + PAD) for t, e, s in recs)


def _nats_stream(recs) -> bytes:
    return b"".join(b"MSG c%d %d 48\r\n%s\r\n" % (7 + e, 100 + s, PAYLOAD.pack(t, e, s) + PAD) for t, e, s in recs)


def test_scanner_finds_every_record_across_any_split():
    recs = [(100.0 + i, i % 7, i) for i in range(50)]
    for pattern, data in ((OursDriver.pattern, _ours_stream(recs)), (RedisDriver.pattern, _redis_stream(recs)),
                          (NatsDriver.pattern, _nats_stream(recs))):
        for cut in (1, 7, 33, 64, 1000):
            sc = Scanner(pattern)
            heads = []
            for i in range(0, len(data), cut):
                heads += sc.feed(data[i : i + cut])
            assert [PAYLOAD.unpack(h) for h in heads] == recs


def test_tally_counts_each_viewer_entity_seq_once_within_the_window():
    t = Tally(2, 5)
    t.window = (10.0, 20.0)
    h = [PAYLOAD.pack(9.0, 1, 1), PAYLOAD.pack(9.0, 1, 1), PAYLOAD.pack(9.0, 1, 2), PAYLOAD.pack(9.0, 2, 1)]
    t.add(0, h, 9.5)  # before the window: deduplicated but not counted
    t.add(0, [PAYLOAD.pack(10.0, 1, 2), PAYLOAD.pack(10.0, 1, 3)], 10.01)  # seq 2 already seen
    t.add(1, [PAYLOAD.pack(10.0, 1, 3)], 10.02)  # another viewer: counts
    t.add(1, [PAYLOAD.pack(10.0, 4, 1)], 25.0)  # after the window
    t.flush()
    assert t.count == 2
    assert t.dups == 2
    assert abs(t.quantile(0.5) - 10.0) < 0.2 and abs(t.quantile(1.0) - 20.0) < 0.2


def test_publish_bytes_decode():
    d = OursDriver(1, "x")
    msgs = P.decode_payload(d.publish_bytes([(3, 4, (5, 6), 700)], 1.5)[4:])
    assert msgs[0].entity == 3 and msgs[0].cells == (5, 6) and PAYLOAD.unpack_from(msgs[0].payload) == (1.5, 3, 4)
    redis = RedisDriver(1).publish_bytes([(3, 4, (5, 6), 700)], 1.5)
    payload = PAYLOAD.pack(1.5, 3, 4) + PAD
    assert redis == _resp(b"PUBLISH", b"c5", payload) + _resp(b"PUBLISH", b"c6", payload)


def test_the_servers_queue_latency_is_read_from_two_scrapes_of_its_histogram():
    """p50 / p99 as the upper bound of the bucket holding them, over the window only (the difference of two
    scrapes); None past the last finite bound or with no sample."""
    from sims.bench.switch_bench import QUEUE_BUCKET, queue_latency

    bounds = ["0.001", "0.0025", "0.005", "0.01", "0.02", "0.05", "0.1", "0.25", "0.5", "1.0", "2.5", "+Inf"]

    def scrape(cum):
        return {f'{QUEUE_BUCKET}{b}"}}': float(c) for b, c in zip(bounds, cum, strict=True)} | {"other": 1.0}

    before = scrape([5, 5, 5, 5, 5, 5, 5, 5, 5, 5, 5, 5])  # five samples before the window: not counted
    got = queue_latency(before, scrape([15, 25, 45, 75, 95, 103, 104.5, 105, 105, 105, 105, 105]))
    assert got == {"server_queue_latency_samples": 100.0, "server_queue_latency_p50_le_ms": 10.0,
                   "server_queue_latency_p99_le_ms": 100.0}
    slow = queue_latency(scrape([0] * 12), scrape([0] * 10 + [40, 100]))
    assert slow["server_queue_latency_p50_le_ms"] is None and slow["server_queue_latency_p99_le_ms"] is None
    assert queue_latency({}, {})["server_queue_latency_p50_le_ms"] is None
    assert queue_latency(before, before)["server_queue_latency_samples"] == 0.0
