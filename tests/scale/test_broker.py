"""The NATS connection: a cluster's servers given as one list, the first one down."""

from __future__ import annotations

from kybercore.scale.broker import LocalServer, connect, servers
from kybercore.sim.stack import free_port


def test_a_clusters_servers_are_separated_by_commas() -> None:
    assert servers("nats://a:4222, nats://b:4222,,c:4223 ") == [
        "nats://a:4222",
        "nats://b:4222",
        "c:4223",
    ]
    assert servers("nats://a:4222") == ["nats://a:4222"]


async def test_a_list_connects_to_a_server_that_is_up(nats_server: LocalServer) -> None:
    # nats-py takes one string as one server: "a,b" used to be an invalid URL.
    nc = await connect(f"nats://127.0.0.1:{free_port()},{nats_server.url}", "test")
    try:
        assert nc.connected_url is not None
        assert nc.connected_url.port == nats_server.port
        await nc.flush()
    finally:
        await nc.close()
