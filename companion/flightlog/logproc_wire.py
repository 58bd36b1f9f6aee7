"""The messages between a process and its logging process: length-prefixed pickles over a Unix
socket, each a list of ops (tuples naming what to do first) or one reply."""

from __future__ import annotations

import pickle
import socket
import struct
from typing import Any

HEADER = struct.Struct("!Q")
Op = tuple[Any, ...]


def send(sock: socket.socket, obj: object) -> None:
    data = pickle.dumps(obj, protocol=5)
    sock.sendall(HEADER.pack(len(data)))
    sock.sendall(data)


def recv_exact(sock: socket.socket, n: int) -> bytes:
    buf = bytearray(n)
    view = memoryview(buf)
    got = 0
    while got < n:
        k = sock.recv_into(view[got:])
        if k == 0:
            raise EOFError("the logging process closed its end")
        got += k
    return bytes(buf)


def recv(sock: socket.socket) -> Any:
    (n,) = HEADER.unpack(recv_exact(sock, HEADER.size))
    return pickle.loads(recv_exact(sock, n))
