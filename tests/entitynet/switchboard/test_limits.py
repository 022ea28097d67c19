"""The core's bounds on what one client can cause (issue 9): subscription churn, replies per frame, the size of
a query result."""

from __future__ import annotations

from entitynet import protocol as P
from entitynet.protocol import ErrorCode
from tests.entitynet.switchboard_helpers import join, make, of, pub, recv


def test_subscription_churn_over_budget_is_refused_and_refills():
    sb = make(n_cells=1000, churn_rate=100.0, churn_burst=2500.0)
    c = join(sb)
    all_cells = tuple(range(1000))
    sb.receive(c, [P.Subscribe(all_cells, ()), P.Subscribe((), all_cells), P.Subscribe(all_cells, ())], 0.0)
    got = recv(sb, c)
    errs = of(got, P.Error)
    assert [e.code for e in errs] == [ErrorCode.LIMIT_CHURN]  # 1000 + 1000 pass, the third 1000 does not
    assert "cells/s" in errs[0].text and "unchanged" in errs[0].text
    assert sb.clients[c].subs == set()
    assert sb.stats["churn_refused"] == 1 and sb.errors[int(ErrorCode.LIMIT_CHURN)] == 1
    # the budget refills at churn_rate: 500 left + 4 s x 100 cells/s = 900 cells, not 901
    sb.receive(c, [P.Subscribe(all_cells[:901], ())], 4.0)
    assert [e.code for e in of(recv(sb, c), P.Error)] == [ErrorCode.LIMIT_CHURN]
    sb.receive(c, [P.Subscribe(all_cells[:900], ())], 4.0)
    assert of(recv(sb, c), P.Error) == []
    assert len(sb.clients[c].subs) == 900


def test_churn_counts_only_cells_that_change():
    sb = make(n_cells=100, churn_rate=0.0, churn_burst=10.0)
    c = join(sb)
    sb.receive(c, [P.Subscribe(tuple(range(10)), ())] + [P.Subscribe(tuple(range(10)), ())] * 50, 0.0)
    assert of(recv(sb, c), P.Error) == []  # re-sending the same cells changes nothing and costs nothing
    sb.receive(c, [P.Subscribe((10,), ())], 0.0)
    assert [e.code for e in of(recv(sb, c), P.Error)] == [ErrorCode.LIMIT_CHURN]


def test_the_churn_budget_is_announced_in_welcome():
    sb = make(churn_rate=1234.0, churn_burst=5678.0)
    cid = sb.connect(0.0)
    sb.receive(cid, [P.Hello(P.PROTOCOL_VERSION, "", "d")], 0.0)
    (w,) = recv(sb, cid)
    assert w.limits["churn_rate"] == 1234 and w.limits["churn_burst"] == 5678
    assert w.limits["max_replies_per_frame"] == sb.config.max_replies_per_frame
    assert w.limits["max_query_results"] == sb.config.max_query_results


def test_too_many_replies_in_one_frame_are_refused_with_one_error_and_the_client_stays():
    sb = make()  # max_control 1000, max_replies_per_frame 500
    c = join(sb)
    sb.receive(c, [P.Ping(i) for i in range(1001)], 1.0)
    got = recv(sb, c)
    pongs = of(got, P.Pong)
    assert [p.client_ms for p in pongs] == list(range(500))
    (err,) = of(got, P.Error)
    assert err.code == ErrorCode.TOO_MANY_REQUESTS and "501 requests" in err.text
    assert not sb.clients[c].closing and sb.stats["slow_consumers"] == 0
    # the bound is per frame: the next frame is answered again
    sb.receive(c, [P.Ping(7)], 2.0)
    assert of(recv(sb, c), P.Pong) == [P.Pong(7, 2000)]


def test_reply_bound_counts_errors_and_queries_and_spans_slices_of_one_frame():
    sb = make(max_replies_per_frame=10, query_burst=100.0)
    c = join(sb)
    msgs = [P.Unfollow(5)] * 4 + [P.Query(i, P.QUERY_CELLS, (1,)) for i in range(4)] + [P.Ping(1)] * 4
    sb.receive(c, msgs[:6], 0.0, frame_end=False)
    sb.receive(c, msgs[6:], 0.0)
    got = recv(sb, c)
    assert len(of(got, P.Error)) == 5  # 4 NO_SUCH_ENTITY + 1 TOO_MANY_REQUESTS
    assert len(of(got, P.QueryResult)) == 4 and len(of(got, P.Pong)) == 2
    assert of(got, P.Error)[-1].code == ErrorCode.TOO_MANY_REQUESTS and "2 requests" in of(got, P.Error)[-1].text
    assert sb.stats["queries"] == 4


def test_query_result_is_bounded_to_one_frame():
    sb = make(n_cells=10, max_entities_per_client=5000)
    owner, asker = join(sb), join(sb)
    big = b"p" * 2000
    sb.receive(owner, [pub(i, 1, (3,), payload=big) for i in range(900)], 0.0)
    sb.receive(asker, [P.Query(1, P.QUERY_CELLS, (3,))], 0.0)
    sb.take_dirty()
    (enc,) = sb.outbox(asker).drain()
    assert len(enc) + 5 <= sb.config.codec.max_frame  # fits in one frame with the payload's array header
    (res,) = P.decode_payload(P.payload_from_encoded([enc]))
    assert isinstance(res, P.QueryResult) and res.query_id == 1
    assert 400 < len(res.entities) < 900 and all(u.payload == big for u in res.entities)
    assert sb.stats["query_results_cut"] == 1


def test_encode_query_result_matches_the_codec():
    u = P.Update(2**40, 3, (1, 2), 500, b"x", "bob")
    ref = P.encode_message(P.QueryResult(77, (u, u)))
    assert P.encode_query_result(77, [P.encode_message(u)] * 2) == ref
    assert P.encode_query_result(5, []) == P.encode_message(P.QueryResult(5, ()))
