# SPDX-License-Identifier: Apache-2.0
"""The exception every failed call raises."""
from __future__ import annotations

import grpc


class PliantError(Exception):
    """A call the server refused or could not answer.

    ``code`` is the gRPC status code (``grpc.StatusCode``), ``code_name`` its name
    ("NOT_FOUND", ...), ``details`` the server's message (it names the field and the value).
    """

    def __init__(self, code: grpc.StatusCode, details: str, call: str = "") -> None:
        self.code = code
        self.code_name = code.name if code is not None else "UNKNOWN"
        self.details = details or ""
        self.call = call
        where = f"{call}: " if call else ""
        super().__init__(f"{where}{self.code_name}: {self.details}")

    @classmethod
    def from_rpc_error(cls, err: grpc.RpcError, call: str = "") -> "PliantError":
        code = err.code() if hasattr(err, "code") else grpc.StatusCode.UNKNOWN
        details = err.details() if hasattr(err, "details") else str(err)
        return cls(code, details or "", call)
