"""A generator run ahead in a background thread: decoding and cropping (inference) or batch
preparation (training) overlap with the network."""

from __future__ import annotations

import queue
import threading
from typing import Callable, Iterator


def threaded(gen_fn: Callable[[], Iterator], maxsize: int) -> Iterator:
    """Run a generator in a thread; yield its items (exceptions re-raised here)."""
    q: queue.Queue = queue.Queue(maxsize=maxsize)
    done = object()
    stop = threading.Event()

    def work():
        try:
            for item in gen_fn():
                while not stop.is_set():
                    try:
                        q.put(item, timeout=0.2)
                        break
                    except queue.Full:
                        continue
                if stop.is_set():
                    return
            q.put(done)
        except BaseException as e:  # noqa: BLE001 - handed to the consumer
            q.put(e)

    th = threading.Thread(target=work, daemon=True)
    th.start()
    try:
        while True:
            item = q.get()
            if item is done:
                return
            if isinstance(item, BaseException):
                raise item
            yield item
    finally:
        stop.set()
        th.join(timeout=5)
