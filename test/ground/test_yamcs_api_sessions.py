"""yamcs_api's kept clients (one per server, login and thread): stopping a server closes this process's clients
of it, of every thread and host name, and no other's (their session renewal would call a server that is gone)."""

from __future__ import annotations

from taiji2_ground_pkg.mcs import yamcs_api


class _Client:
    closed = False

    def close(self):
        self.closed = True


def test_close_sessions_closes_the_clients_of_that_port_only(monkeypatch):
    clients = {("127.0.0.1:8090", None, 1): _Client(), ("localhost:8090", ("op", "pw"), 2): _Client(),
               ("127.0.0.1:18090", None, 1): _Client()}
    monkeypatch.setattr(yamcs_api, "_CLIENTS", dict(clients))
    yamcs_api.close_sessions(8090)
    assert set(yamcs_api._CLIENTS) == {("127.0.0.1:18090", None, 1)}
    assert [c.closed for c in clients.values()] == [True, True, False]
