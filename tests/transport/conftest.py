"""Fixtures for the transport tests (the peers live in transport_peers.py)."""

from transport_peers import pty_pair, pty_responder, tcp_peer

__all__ = ["pty_pair", "pty_responder", "tcp_peer"]
