# SPDX-License-Identifier: Apache-2.0
"""Which server holds a scene: rendezvous (highest-random-weight) hashing of the scene id.

The rule (docs/deploy.md, "Scene placement"), the same bit for bit in the C++ client
(``pliant/client/placement.hpp``):

    score(id, k) = mix64(fnv1a64(utf8(id) + b"\\x00" + ascii(decimal k)))
    owner(id, n) = the k in [0, n) with the highest score (the lowest k on a tie)

fnv1a64 is 64-bit FNV-1a (offset basis 0xcbf29ce484222325, prime 0x100000001b3); mix64 is the
64-bit finalizer of MurmurHash3 (xor-shift 33, multiply 0xff51afd7ed558ccd, xor-shift 33,
multiply 0xc4ceb93e2d7d4a03, xor-shift 33). k is the server's position in the ordered list
(its StatefulSet ordinal), not its address, so a client that reaches the servers through other
names (port forwards, IPs) places scenes the same way. Adding server n moves only the scenes
whose new owner is n; removing the last server moves only its scenes.
"""
from __future__ import annotations

from typing import Optional, Sequence

_MASK = (1 << 64) - 1
FNV_OFFSET = 0xCBF29CE484222325
FNV_PRIME = 0x100000001B3


def fnv1a64(data: bytes) -> int:
    """64-bit FNV-1a of ``data``."""
    h = FNV_OFFSET
    for b in data:
        h ^= b
        h = (h * FNV_PRIME) & _MASK
    return h


def mix64(h: int) -> int:
    """MurmurHash3's 64-bit finalizer (spreads every input bit over the output)."""
    h &= _MASK
    h ^= h >> 33
    h = (h * 0xFF51AFD7ED558CCD) & _MASK
    h ^= h >> 33
    h = (h * 0xC4CEB93E2D7D4A03) & _MASK
    h ^= h >> 33
    return h


def score(scene_id: str, ordinal: int) -> int:
    """The weight of server ``ordinal`` for ``scene_id``."""
    if ordinal < 0:
        raise ValueError(f"ordinal must be >= 0, got {ordinal}")
    return mix64(fnv1a64(scene_id.encode("utf-8") + b"\x00" + str(ordinal).encode("ascii")))


def owner_index(scene_id: str, server_count: int) -> int:
    """The position, in an ordered list of ``server_count`` servers, of the one holding ``scene_id``."""
    if not scene_id:
        raise ValueError("scene_id must not be empty (placement needs the id)")
    if server_count < 1:
        raise ValueError(f"server_count must be >= 1, got {server_count}")
    best, best_score = 0, -1
    for k in range(server_count):
        s = score(scene_id, k)
        if s > best_score:
            best, best_score = k, s
    return best


def owner(scene_id: str, servers: Sequence[str]) -> str:
    """The address, out of the ordered list ``servers``, of the server holding ``scene_id``."""
    if not servers:
        raise ValueError("servers must list at least one address")
    return servers[owner_index(scene_id, len(servers))]


def statefulset_servers(name: str, replicas: int, *, service: Optional[str] = None,
                        namespace: str = "default", port: int = 50051) -> list[str]:
    """The ordered addresses of a StatefulSet's pods behind its headless Service:
    ``NAME-k.SERVICE.NAMESPACE.svc:PORT`` for k = 0 .. replicas-1 (deploy/k8s/sharded.yaml)."""
    if replicas < 1:
        raise ValueError(f"replicas must be >= 1, got {replicas}")
    svc = service or name
    return [f"{name}-{k}.{svc}.{namespace}.svc:{port}" for k in range(replicas)]


def parse_servers(text: str) -> list[str]:
    """``"a:1,b:2"`` -> ``["a:1", "b:2"]``; rejects empty entries and duplicates."""
    servers = [s.strip(" ") for s in text.split(",")]
    if not text.strip(" ") or any(not s for s in servers):
        raise ValueError(f"servers must be a comma-separated list of HOST:PORT, got {text!r}")
    seen = set()
    for s in servers:
        if s in seen:
            raise ValueError(f"servers lists {s!r} twice in {text!r}")
        seen.add(s)
    return servers
