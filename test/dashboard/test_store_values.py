"""The sample store (every row after a cursor, losses counted past its bound) and the reading
of typed text as parameter values."""
from __future__ import annotations

import json
import math
import threading

from tank_control.dashboard import values as V
from tank_control.dashboard.store import SampleStore


def test_a_reader_gets_every_row_once_in_order_while_a_writer_adds():
    store = SampleStore(capacity=100_000)
    total = 20_000
    writer = threading.Thread(target=lambda: [store.add('measurement', k * 0.01, ('y',), (k,))
                                              for k in range(total)])
    writer.start()
    cursor, got = store.oldest_cursor(), []
    while len(got) < total:
        batch = store.since(cursor, limit=700)
        assert batch.lost == 0
        got += [row.values[0] for row in batch.rows]
        cursor = batch.cursor
    writer.join()
    assert got == list(range(total))


def test_a_reader_behind_the_bound_is_told_how_many_rows_it_lost():
    store = SampleStore(capacity=10)
    for k in range(25):
        store.add('setpoint', float(k), ('r',), (float(k),))
    batch = store.since(3)
    assert batch.lost == 25 - 10 - 3          # rows 4 … 15 were dropped, 16 … 25 are held
    assert [row.seq for row in batch.rows] == list(range(16, 26))
    assert store.since(batch.cursor).rows == []


def test_a_batch_message_aligns_channels_and_is_valid_json():
    store = SampleStore(capacity=100)
    store.add('manipulated', 0.0, ('a',), (1.0,))
    store.add('manipulated', 0.1, ('a', 'b'), (2.0, math.nan))
    store.add('manipulated', 0.2, ('b',), (3.0,))
    message = json.loads(json.dumps(store.since(0).as_message(), allow_nan=False))
    topic = message['topics']['manipulated']
    assert topic == {'t': [0.0, 0.1, 0.2], 'ch': {'a': [1.0, 2.0, None], 'b': [None, None, 3.0]}}
    assert (message['first'], message['last'], message['lost']) == (1, 3, 0)


def test_typed_text_is_read_by_the_parameter_type_and_left_as_text_otherwise():
    assert V.parse_text('2', V.DOUBLE) == 2.0 and isinstance(V.parse_text('2', V.DOUBLE), float)
    assert V.parse_text('inf', V.DOUBLE) == math.inf
    assert V.parse_text('abc', V.DOUBLE) == 'abc'          # the node refuses it with its reason
    assert V.parse_text('7', V.INTEGER) == 7
    assert V.parse_text('true', V.BOOL) is True and V.parse_text('off', V.BOOL) is False
    assert V.parse_text('[1, 2.5]', V.DOUBLE_ARRAY) == [1.0, 2.5]
    assert V.parse_text('1, 2', V.DOUBLE_ARRAY) == [1.0, 2.0]
    assert V.parse_text('["y", "z"]', V.STRING_ARRAY) == ['y', 'z']
    assert V.parse_text('y, z', V.STRING_ARRAY) == ['y', 'z']
    assert V.parse_text('manual', V.STRING) == 'manual'
    assert V.jsonable([math.inf, -math.inf, 1.5, (2, 3)]) == ['inf', '-inf', 1.5, [2, 3]]


def test_text_a_parameter_message_cannot_carry_is_sent_as_text():
    """An integer beyond 64 bits, a number too large for a double, nested or null items: the
    text itself (the node refuses it with its reason); before, an integer beyond 64 bits made
    the service request fail inside the dashboard's executor and the node died."""
    from tank_control.nodes.dashboard_requests import parameter_msg
    for text, kind in (('-9223372036854775809', V.INTEGER), ('1' + '0' * 30, V.INTEGER),
                       ('[1' + '0' * 400 + ']', V.DOUBLE_ARRAY),
                       ('[1' + '0' * 30 + ']', V.INTEGER_ARRAY), ('[[1]]', V.INTEGER_ARRAY),
                       ('[{"a": 1}]', V.DOUBLE_ARRAY), ('[null]', V.DOUBLE_ARRAY)):
        assert V.parse_text(text, kind) == text
        assert parameter_msg('p', text, kind).value.string_value == text
    assert V.parse_text('9223372036854775807', V.INTEGER) == 2 ** 63 - 1
    assert V.parse_text('[1, 2]', V.INTEGER_ARRAY) == [1, 2]
