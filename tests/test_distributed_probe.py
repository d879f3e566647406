"""A Ray address where nothing listens fails in seconds, in one line (not after Ray's minutes of retries)."""

from __future__ import annotations

import socket
import time

import pytest

from nsim.distributed import check_ray_address, ray_endpoint, ray_session
from nsim.errors import NsimError


@pytest.fixture
def closed_port() -> int:
    """A local TCP port that nothing listens on (bound, then released)."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_endpoints():
    assert ray_endpoint("local") is None and ray_endpoint("auto") is None
    assert ray_endpoint("head:6379") == ("head", 6379)
    assert ray_endpoint("10.0.0.5:6380") == ("10.0.0.5", 6380)
    assert ray_endpoint("[::1]:6379") == ("::1", 6379)
    assert ray_endpoint("ray://head:10002") == ("head", 10002)
    assert ray_endpoint("ray://head") == ("head", 10001)  # the Ray client's default port
    assert ray_endpoint("anyscale://cluster") is None  # other schemes: Ray's to resolve
    for bad in ("head", "head:port", "head:0", "head:70000", ":6379", "::1:6379"):
        with pytest.raises(NsimError, match=rf"^{bad}: not a Ray address \(expected HOST:PORT"):
            ray_endpoint(bad)


def test_listening_address_passes():
    with socket.socket() as server:
        server.bind(("127.0.0.1", 0))
        server.listen()
        port = server.getsockname()[1]
        check_ray_address(f"127.0.0.1:{port}", "--address")
        check_ray_address(f"ray://127.0.0.1:{port}", "--address")
    check_ray_address("local", "--address")  # nothing to dial


@pytest.mark.parametrize("form", ["{}", "ray://{}"])
def test_closed_port_fails_fast_in_one_line(closed_port, form):
    address = form.format(f"127.0.0.1:{closed_port}")
    t0 = time.monotonic()
    with pytest.raises(NsimError) as err:
        check_ray_address(address, "$RAY_ADDRESS")
    assert time.monotonic() - t0 < 60  # refused at once (Ray itself would retry for minutes); generous when busy
    msg = str(err.value)
    assert msg.startswith(f"$RAY_ADDRESS {address}: cannot connect to a Ray cluster there (127.0.0.1:{closed_port}: ")
    assert "\n" not in msg


def test_unanswering_host_times_out(monkeypatch):
    seen = []

    def silent(address, timeout):  # a host that drops the SYN (the network here may answer for any host)
        seen.append((address, timeout))
        raise TimeoutError("timed out")

    monkeypatch.setattr(socket, "create_connection", silent)
    with pytest.raises(NsimError, match=r"^--address head:6379: cannot connect .*\(head:6379: no answer within 0\.3 s\)$"):
        check_ray_address("head:6379", "--address", timeout_s=0.3)
    assert seen == [(("head", 6379), 0.3)]


def test_auto_probes_what_ray_would_join(closed_port, monkeypatch):
    monkeypatch.setenv("RAY_ADDRESS", f"127.0.0.1:{closed_port}")  # ray.init("auto") prefers $RAY_ADDRESS
    with pytest.raises(NsimError, match=rf"^--address auto \(127\.0\.0\.1:{closed_port}\): cannot connect"):
        check_ray_address("auto", "--address")


def test_ray_session_fails_fast(closed_port, monkeypatch):
    ray = pytest.importorskip("ray")
    if ray.is_initialized():
        pytest.skip("this process already runs Ray (ray_session reuses it)")
    monkeypatch.setenv("RAY_ADDRESS", f"127.0.0.1:{closed_port}")

    def no_init(*args, **kwargs):  # the probe must refuse before Ray's own connection retries start
        raise AssertionError("ray.init was reached")

    monkeypatch.setattr(ray, "init", no_init)
    t0 = time.monotonic()
    with pytest.raises(NsimError, match=rf"^\$RAY_ADDRESS 127\.0\.0\.1:{closed_port}: cannot connect"):
        with ray_session(None, num_cpus=1):
            pass
    assert time.monotonic() - t0 < 60  # Ray itself would retry for minutes; generous for a busy machine
    assert not ray.is_initialized()
