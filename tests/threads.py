"""Shared test helper: calls from several threads give what the same calls give one after another."""

import threading

import numpy as np


def assert_concurrent_calls_match(fn, inputs) -> None:
    """Run ``fn(x)`` for every x in ``inputs`` sequentially, then all at once in threads, and
    require identical arrays."""
    expected = [fn(x) for x in inputs]
    results = [None] * len(inputs)

    def work(i):
        results[i] = fn(inputs[i])

    threads = [threading.Thread(target=work, args=(i,)) for i in range(len(inputs))]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    for got, want in zip(results, expected):
        np.testing.assert_array_equal(got, want)
