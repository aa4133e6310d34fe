# SPDX-License-Identifier: Apache-2.0
"""Python client for Pliant, the real-time soft-body simulation service (docs/python.md).

    import pliant
    with pliant.Client("127.0.0.1:50051") as c:
        c.create_scene("demo", "beam1", young_modulus=1e6, rate_hz=60, fix_x_below=0.001)
        for frame in c.frames("demo"):
            print(frame.tick, frame.positions.shape)

The gRPC stubs (pliant.v1) are generated at build time into the build tree's python/ folder.
"""
from .errors import PliantError
from .placement import owner, owner_index, parse_servers, statefulset_servers
from .client import (Client, Frame, FrameStream, HapticSession, ShardedClient, ToolFeedback,
                     Topology)
from .v1 import pliant_pb2 as pb

__all__ = ["Client", "ShardedClient", "Frame", "FrameStream", "HapticSession", "ToolFeedback",
           "Topology", "PliantError", "owner", "owner_index", "parse_servers",
           "statefulset_servers", "pb"]
