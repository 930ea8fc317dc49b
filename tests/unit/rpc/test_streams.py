"""Zenoh streams: a publisher that starts before its router still streams once the router is up."""

from __future__ import annotations

import contextlib
import queue
import subprocess
import sys
import time

import pytest
from sqmanip import streams
from sqmanip.launch import settings_on_free_ports
from sqmanip.v1 import common_pb2


def test_publisher_started_before_the_router_connects_when_it_comes_up() -> None:
    settings = settings_on_free_ports()
    publisher = streams.Publisher("sqmanip/test/scene", retry_s=0.2)
    publisher.open(settings)
    time.sleep(0.5)
    assert not publisher.connected
    publisher.publish(common_pb2.Scene())  # dropped, not raised
    router = subprocess.Popen(
        [sys.executable, "-m", "sqmanip.streams", "--listen", settings.zenoh_endpoint]
    )
    try:
        deadline = time.monotonic() + 20
        while not publisher.connected and time.monotonic() < deadline:
            time.sleep(0.1)
        assert publisher.connected
        session, sub = streams.subscribe("sqmanip/test/**", settings)
        try:
            sent = common_pb2.Scene(objects=[common_pb2.RecognizedObject(id=3)])
            for _ in range(20):  # until the subscription has reached the publisher
                publisher.publish(sent)
                with contextlib.suppress(queue.Empty):
                    key, payload = sub.get(timeout=0.5)
                    break
            else:
                pytest.fail("no sample after 20 puts")
        finally:
            sub.close()
            session.close()
    finally:
        publisher.close()
        router.terminate()
        router.wait(10)
    assert key == "sqmanip/test/scene"
    assert common_pb2.Scene.FromString(payload) == sent


def test_publisher_is_a_no_op_when_zenoh_is_disabled() -> None:
    publisher = streams.Publisher("sqmanip/test/scene")
    publisher.open(settings_on_free_ports(zenoh_enabled=False))
    publisher.publish(common_pb2.Scene())
    assert not publisher.connected
    publisher.close()
