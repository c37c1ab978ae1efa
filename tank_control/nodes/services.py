"""Service calls that survive a lost response.

``client.service_is_ready()`` only tells that the client's side has matched the server.
rmw_fastrtps drops a response whose server has not matched the client's response reader
within 100 ms ("client will not receive response" in the server's log), which happens on a
loaded machine while discovery is still going on; the client then waits in vain. A request
that may be repeated without effect (a read: list, get, describe parameters) is therefore
sent again when no answer came, first after ``resend_after`` s, then after twice as long, ...
A request with an effect (a set) is sent once, and only after ``prime`` has had an answer
to a request without effect on the same client (an empty SetParameters changes nothing):
that answer proves the server matched this client's response reader, so the set's
response cannot be lost that way.
"""
from __future__ import annotations

import time
from collections.abc import Callable, Hashable, Mapping
from typing import Any

#: [s] a read without an answer is sent again after this long (then 2×, 4×, ...).
RESEND_AFTER = 2.0

Spin = Callable[[Callable[[], bool], float], bool]
"""``spin(condition, timeout)``: spin until ``condition()`` (True) or ``timeout`` s (False)."""


def answers(calls: Mapping[Hashable, tuple[Any, Any]], spin: Spin, timeout: float,
            resend_after: float | None = None) -> dict[Hashable, Any | None]:
    """Key → the first done future of ``calls[key] = (client, request)`` within ``timeout`` s,
    else None; requests without an answer sent again as the module docstring says when
    ``resend_after`` [s] is given. The requests go out together: their waits overlap."""
    deadline = time.monotonic() + timeout
    sent = {key: [client.call_async(request)] for key, (client, request) in calls.items()}

    def done(key: Hashable) -> Any | None:
        return next((f for f in sent[key] if f.done()), None)
    wait = resend_after
    while True:
        remaining = max(0.0, deadline - time.monotonic())
        if spin(lambda: all(done(key) is not None for key in sent),
                remaining if wait is None else min(wait, remaining)):
            break
        if time.monotonic() >= deadline:
            break
        if wait is None:
            continue                    # no re-sends: spin on to the deadline
        for key, (client, request) in calls.items():
            if done(key) is None:
                sent[key].append(client.call_async(request))
        wait *= 2
    return {key: done(key) for key in sent}


def answer(client: Any, request: Any, spin: Spin, timeout: float,
           resend_after: float | None = None) -> Any | None:
    """The first done future of ``request`` on ``client`` within ``timeout`` s, else None
    (``answers`` of one call)."""
    return answers({None: (client, request)}, spin, timeout, resend_after)[None]


def prime(client: Any, empty_request: Any, spin: Spin, timeout: float,
          resend_after: float = RESEND_AFTER) -> bool:
    """Send ``empty_request`` (a request without effect, e.g. ``SetParameters.Request()``)
    on ``client`` until one is answered (resent as for a read); False after ``timeout`` s.

    Afterwards a request with an effect on the same client is sent once and its response
    reaches the client (module docstring).
    """
    return answer(client, empty_request, spin, timeout, resend_after) is not None
