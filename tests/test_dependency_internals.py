"""The private names of python-can and canopen that nurbsmotion leans on are still there.

``socketcan_batch.BatchNotifier`` overrides python-can's ``Notifier._rx_thread`` and reads
``_stopped``, ``_lock``, ``_loop``, ``_on_message_received`` and ``_on_error``;
``fieldbus.bringup.SdoTrail`` wraps canopen's ``SdoClient.upload``/``download``. pyproject.toml
bounds both packages at the versions tested; if a new release is allowed in and renames one
of these, this test says which name to port, instead of a receive thread that silently
never runs.
"""

from __future__ import annotations

import inspect

import can
import canopen
import pytest
from canopen.sdo.client import SdoClient

NOTIFIER_METHODS = ("_rx_thread", "_on_message_received", "_on_error")
NOTIFIER_ATTRIBUTES = ("_stopped", "_lock", "_loop", "exception", "timeout")


@pytest.mark.parametrize("name", NOTIFIER_METHODS)
def test_python_can_notifier_still_has_the_methods_batch_notifier_overrides(name: str) -> None:
    assert callable(getattr(can.Notifier, name, None)), (
        f"python-can {can.__version__}: can.Notifier.{name} is gone; port socketcan_batch.BatchNotifier")


@pytest.mark.parametrize("name", NOTIFIER_ATTRIBUTES)
def test_python_can_notifier_still_sets_the_attributes_batch_notifier_reads(name: str) -> None:
    bus = can.Bus(interface="virtual", channel="dependency-internals")
    notifier = can.Notifier(bus, [])
    try:
        assert hasattr(notifier, name), (
            f"python-can {can.__version__}: Notifier no longer sets {name}; port socketcan_batch.BatchNotifier")
    finally:
        notifier.stop()
        bus.shutdown()


def test_python_can_rx_thread_still_takes_the_bus() -> None:
    params = list(inspect.signature(can.Notifier._rx_thread).parameters)
    assert params == ["self", "bus"], f"python-can {can.__version__}: Notifier._rx_thread{params}"


def test_canopen_sdo_client_upload_and_download_keep_the_signatures_sdo_trail_wraps() -> None:
    download = list(inspect.signature(SdoClient.download).parameters)
    upload = list(inspect.signature(SdoClient.upload).parameters)
    assert download == ["self", "index", "subindex", "data", "force_segment"], (
        f"canopen {canopen.__version__}: SdoClient.download{download}; port fieldbus.bringup.SdoTrail")
    assert upload == ["self", "index", "subindex"], (
        f"canopen {canopen.__version__}: SdoClient.upload{upload}; port fieldbus.bringup.SdoTrail")


def test_canopen_sdo_client_still_has_what_sdo_arrival_replaces_and_reads():
    """fieldbus.sdo_arrival replaces SdoClient.send_request/read_response and reads its
    ``responses`` queue and the RESPONSE_ABORTED constant."""
    from canopen.sdo.constants import RESPONSE_ABORTED  # noqa: F401 - an ImportError names what moved

    assert callable(getattr(SdoClient, "send_request", None)), f"canopen {canopen.__version__}: SdoClient.send_request"
    assert callable(getattr(SdoClient, "read_response", None)), f"canopen {canopen.__version__}: SdoClient.read_response"
    network = canopen.Network()
    client = SdoClient(0x600 + 1, 0x580 + 1, canopen.ObjectDictionary())
    client.network = network
    assert hasattr(client, "responses"), f"canopen {canopen.__version__}: SdoClient.responses; port fieldbus.sdo_arrival"
