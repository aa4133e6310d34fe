#!/usr/bin/env bash
# SPDX-License-Identifier: Apache-2.0
# docker/smoke-test.sh - build the Pliant server image from this checkout with podman and use it:
# check the image (non-root user, port, volume, HEALTHCHECK, every library found, no compilers),
# start the container, wait for its HEALTHCHECK, create scenes (one from the image's meshes/) and
# stream frames from the host with the `pliant` CLI, stop it (SIGTERM: the server snapshots its
# scenes to the volume), start it again and check the scenes and their exact state came back, run
# compose.yaml with podman-compose (demo client creates and watches a scene), then clean up.
# Needs root (or sudo), a Debian 12 host and the Debian apt mirrors; no Docker engine and no
# registry (the base image is made with debootstrap).
#
#   bash docker/smoke-test.sh
#
# Exit status: 0 passed, 77 skipped (podman could not be installed; says why), anything else failed.
# Env:
#   PLIANT_PODMAN_CACHE=/var/cache/pliant-podman  podman storage + the debootstrap tarball, kept between
#                        runs so that a rerun reuses the package layers (about 1 GB).
#   FRESH=1              start from nothing: wipe that cache (and the ccache mount in /var/tmp) first.
#   PORT=<free port>     host port the server listens on (host networking); default: a free one.
#   IMAGE=localhost/pliant:smoke  tag of the image built.   CLEAN=1: also delete the image at the end.
#
# Facts these build machines need (see ../shared/tools/container-smoke.sh for the origin):
#  * crun fails here ("cgroups in hybrid mode not supported"): we select runc.
#  * root lacks CAP_SYS_RESOURCE and podman caps RLIMIT_NPROC at 32768, so podman's default rlimits
#    (1048576) cannot be set: we pin default_ulimits to the current hard limits.
#  * Debian 12 has podman 4.3.1 / buildah 1.28: no RUN heredocs, no COPY --link (the Dockerfile uses
#    neither); --format docker is needed to keep HEALTHCHECK.
#  * net.ipv4.ip_forward is 0 here, so published bridge ports are not dependable: the container runs
#    with --network=host and listens on 127.0.0.1:$PORT (compose.yaml uses a normal bridge + ports).
set -euo pipefail
cd "$(dirname "$0")/.."
REPO=$PWD
CACHE=${PLIANT_PODMAN_CACHE:-/var/cache/pliant-podman}
IMAGE=${IMAGE:-localhost/pliant:smoke}
NAME=pliant-smoke-$$
VOL=pliant-smoke-data-$$
TOKEN=smoke-$RANDOM$RANDOM
T0=$(date +%s.%N)

say()  { printf '[smoke %6.1fs] %s\n' "$(awk -v s="$T0" -v e="$(date +%s.%N)" 'BEGIN{print e-s}')" "$*" >&2; }
die()  { say "FAIL: $*"; exit 1; }
skip() { say "SKIPPED: $*"; exit 77; }
timed() {  # timed LABEL CMD...: run CMD and report its duration
  local label=$1 s rc=0; shift; s=$(date +%s.%N)
  "$@" || rc=$?
  say "$(awk -v l="$label" -v s="$s" -v e="$(date +%s.%N)" 'BEGIN{printf "%-22s took %6.1fs", l, e-s}')$([ $rc = 0 ] || echo " (exit $rc)")"
  return $rc
}

SUDO=""
if [ "$(id -u)" -ne 0 ]; then
  command -v sudo >/dev/null && sudo -n true 2>/dev/null || skip "needs root or passwordless sudo to run podman rootful"
  SUDO="sudo -n"
fi

# 1. podman (it builds with its embedded buildah), runc, debootstrap; podman-compose for compose.yaml.
if ! command -v podman >/dev/null || ! command -v runc >/dev/null || ! command -v debootstrap >/dev/null; then
  command -v apt-get >/dev/null || skip "podman is not installed and there is no apt-get to install it"
  say "installing podman runc debootstrap"
  export DEBIAN_FRONTEND=noninteractive
  { $SUDO apt-get update -qq && $SUDO apt-get install -y -qq -o DPkg::Lock::Timeout=600 \
      podman runc debootstrap >/dev/null; } || skip "podman could not be installed (apt-get failed, see above)"
fi
if ! command -v podman-compose >/dev/null && command -v apt-get >/dev/null; then
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq -o DPkg::Lock::Timeout=600 \
    --no-install-recommends podman-compose >/dev/null 2>&1 || say "podman-compose could not be installed"
fi

# 2. podman configuration and storage of our own (does not touch the host's default storage).
[ "${FRESH:-0}" = 1 ] && { say "FRESH=1: wiping $CACHE"; $SUDO rm -rf "$CACHE" /var/tmp/buildah-cache/pliant-* /var/tmp/buildah-cache-0/pliant-* 2>/dev/null || true; }
$SUDO mkdir -p "$CACHE"
hn=$(ulimit -Hn); hu=$(ulimit -Hu)
[ "$hn" = unlimited ] && hn=1048576
{ [ "$hu" = unlimited ] || [ "$hu" -gt 32768 ]; } && hu=32768
printf '[containers]\ndefault_ulimits = ["nofile=%s:%s", "nproc=%s:%s"]\n[engine]\nruntime = "runc"\n' \
  "$hn" "$hn" "$hu" "$hu" | $SUDO tee "$CACHE/containers.conf" >/dev/null
P=($SUDO env CONTAINERS_CONF="$CACHE/containers.conf" podman --root "$CACHE/storage" --runroot "$CACHE/run")

cleanup() {
  local rc=$?
  if [ $rc != 0 ] && "${P[@]}" container exists "$NAME" 2>/dev/null; then
    say "server log (last 40 lines):"; "${P[@]}" logs "$NAME" 2>&1 | tail -40 >&2 || true
  fi
  "${P[@]}" rm -f -v -t 5 "$NAME" "$NAME-cli" >/dev/null 2>&1 || true
  "${P[@]}" volume rm -f "$VOL" >/dev/null 2>&1 || true
  if [ "${CLEAN:-0}" = 1 ]; then "${P[@]}" rmi -f "$IMAGE" >/dev/null 2>&1 || true; fi
  # Untagged layers are the build cache; drop only those unused for a week (bounds the disk use).
  "${P[@]}" image prune -f --filter until=168h >/dev/null 2>&1 || true
  rm -rf "$TMPD"
  exit $rc
}
TMPD=$(mktemp -d)
trap cleanup EXIT

# 3. Base image debian:bookworm-slim, made with debootstrap from the mirror apt uses. The tarball is
#    cached in $CACHE so that a wiped storage does not need debootstrap again (it is refreshed weekly).
apt_mirror() {  # apt_mirror SUITE FALLBACK
  local u
  u=$(awk -v s="$1" '/^URIs:/{u=$2} /^Suites:/{for(i=2;i<=NF;i++) if($i==s){print u; exit}}' \
        /etc/apt/sources.list.d/*.sources 2>/dev/null | head -1)
  [ -n "$u" ] || u=$(sed -E 's/\[[^]]*\]//' /etc/apt/sources.list 2>/dev/null |
                     awk -v s="$1" '$1=="deb" && $3==s {print $2; exit}')
  echo "${u:-$2}"
}
BASE_TAR=$CACHE/debian-bookworm-minbase.tar
if ! "${P[@]}" image exists docker.io/library/debian:bookworm-slim; then
  if [ -z "$(find "$BASE_TAR" -mtime -7 2>/dev/null)" ]; then
    MIRROR=$(apt_mirror bookworm http://deb.debian.org/debian)
    SECURITY=$(apt_mirror bookworm-security http://deb.debian.org/debian-security)
    ROOTFS=$CACHE/rootfs.tmp; $SUDO rm -rf "$ROOTFS"
    timed debootstrap bash -c '"$@" >"$0" 2>&1' "$TMPD/debootstrap.log" \
        $SUDO debootstrap --variant=minbase bookworm "$ROOTFS" "$MIRROR" \
      || { tail -20 "$TMPD/debootstrap.log" >&2; die "debootstrap failed"; }
    # Apt sources like the official image's; no host-specific files (podman provides them).
    $SUDO rm -f "$ROOTFS/etc/apt/sources.list" "$ROOTFS/etc/resolv.conf" "$ROOTFS/etc/hostname"
    printf 'Types: deb\nURIs: %s\nSuites: bookworm bookworm-updates\nComponents: main\nSigned-By: /usr/share/keyrings/debian-archive-keyring.gpg\n\nTypes: deb\nURIs: %s\nSuites: bookworm-security\nComponents: main\nSigned-By: /usr/share/keyrings/debian-archive-keyring.gpg\n' \
      "$MIRROR" "$SECURITY" | $SUDO tee "$ROOTFS/etc/apt/sources.list.d/debian.sources" >/dev/null
    $SUDO rm -rf "$ROOTFS"/var/cache/apt/archives/*.deb "$ROOTFS"/var/lib/apt/lists/* "$ROOTFS"/var/log/*.log
    # Slim it like the official -slim image: no docs, man pages, locales (now or in later installs).
    printf 'path-exclude /usr/share/doc/*\npath-include /usr/share/doc/*/copyright\npath-exclude /usr/share/man/*\npath-exclude /usr/share/info/*\npath-exclude /usr/share/locale/*\npath-include /usr/share/locale/locale.alias\npath-exclude /usr/share/lintian/*\n' \
      | $SUDO tee "$ROOTFS/etc/dpkg/dpkg.cfg.d/docker" >/dev/null
    $SUDO find "$ROOTFS/usr/share/doc" -mindepth 1 ! -name copyright ! -type d -delete
    $SUDO find "$ROOTFS/usr/share/doc" -mindepth 1 -type d -empty -delete
    $SUDO rm -rf "$ROOTFS"/usr/share/man/* "$ROOTFS"/usr/share/info/* "$ROOTFS"/usr/share/lintian/*
    $SUDO find "$ROOTFS/usr/share/locale" -mindepth 1 -maxdepth 1 ! -name locale.alias -exec rm -rf {} +
    $SUDO tar -C "$ROOTFS" -cf "$BASE_TAR.tmp" . && $SUDO mv "$BASE_TAR.tmp" "$BASE_TAR"
    $SUDO rm -rf "$ROOTFS"
  fi
  timed import-base "${P[@]}" import -q "$BASE_TAR" localhost/debian:bookworm-slim >/dev/null
  # So that the Dockerfile's unchanged `FROM debian:bookworm-slim` resolves locally (--pull=never).
  "${P[@]}" tag localhost/debian:bookworm-slim docker.io/library/debian:bookworm-slim
fi
[ "${BASE_ONLY:-0}" = 1 ] && { say "base image ready"; exit 0; }

# 4. Build the image. The package layers come before the sources are copied, so after a source change
#    only the compile step (ccache in a cache mount) and the final COPY run again.
say "building $IMAGE from $REPO"
if ! timed build bash -c '"$@" >"$0" 2>&1' "$TMPD/build.log" \
       "${P[@]}" build --pull=never --network=host --format docker --layers \
       --iidfile "$TMPD/iid" -f docker/Dockerfile -t "$IMAGE" .; then
  tail -60 "$TMPD/build.log" >&2; cp "$TMPD/build.log" "$CACHE/last-build.log" 2>/dev/null || true
  die "image build failed (whole log: $CACHE/last-build.log)"
fi
cp "$TMPD/build.log" "$CACHE/last-build.log" 2>/dev/null || true
# From here on the image is named by its ID, so a concurrent run retagging $IMAGE cannot swap it.
IID=$(cat "$TMPD/iid")
grep -E '^\[[0-9]/[0-9]\] STEP [0-9]+/[0-9]+: (RUN|COPY)|Using cache|^image: ' "$TMPD/build.log" \
  | sed -E 's/^(.{110}).*/\1.../' >&2 || true

# 5. What is in the image: size, user, port, volume, health check, libraries, no compilers.
inspect() { "${P[@]}" image inspect --format "$1" "$IID"; }
size=$(inspect '{{.Size}}')
say "image $IMAGE: $(awk -v s="$size" 'BEGIN{printf "%.0f MB", s/1e6}') ($size bytes; base $(
  "${P[@]}" image inspect --format '{{.Size}}' docker.io/library/debian:bookworm-slim | awk '{printf "%.0f MB", $1/1e6}'))"
user=$(inspect '{{.Config.User}}'); [ -n "$user" ] && [ "${user%%:*}" != 0 ] && [ "${user%%:*}" != root ] \
  || die "image runs as root (USER '$user')"
inspect '{{json .Config.ExposedPorts}}' | grep -q '"50051/tcp"' || die "image does not expose 50051"
inspect '{{json .Config.Volumes}}' | grep -q '"/var/lib/pliant"' || die "no VOLUME /var/lib/pliant"
"${P[@]}" image inspect "$IID" | grep -q '"pliant health' || die "no HEALTHCHECK with pliant health"
"${P[@]}" run --rm --network=none --entrypoint /bin/sh "$IID" -c '
  set -e
  # (gcc-12-base is only the shared libraries'' base package, no compiler)
  ls /usr/local/bin
  for f in /usr/local/bin/*; do
    if ldd "$f" | grep "not found"; then echo "$f misses libraries"; exit 1; fi
  done
  for c in gcc g++ cc c++ cpp clang ld as make cmake ninja; do
    if command -v "$c"; then echo "compiler/build tool in the runtime image: $c"; exit 1; fi
  done
  dev=$(dpkg-query -W -f "\${Package}\n" | grep -E -- "-dev$|^gcc(-[0-9]+)?$|^g\+\+|^cpp|^binutils|^libgcc-[0-9]+-dev" || true)
  [ -z "$dev" ] || { echo "build packages in the runtime image: $dev"; exit 1; }
  [ -d "$PLIANT_MODEL_PATH" ] && echo "meshes: $(ls "$PLIANT_MODEL_PATH" | wc -l) files in $PLIANT_MODEL_PATH"
  echo "runs as $(id -un) ($(id -u)); ldd: all libraries found; no compilers"' >"$TMPD/inspect.log" 2>&1 \
  || { cat "$TMPD/inspect.log" >&2; die "runtime image check failed"; }
grep -v 'systemd' "$TMPD/inspect.log" | sed 's/^/  /' >&2   # (podman: no systemd for health timers)

# 6. Run it: host networking (see the top), snapshots in a named volume, settings from the environment.
PORT=${PORT:-$(python3 -c 'import socket; s=socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])')}
ADDR=127.0.0.1:$PORT
"${P[@]}" volume create "$VOL" >/dev/null
start_server() {
  # The image's HEALTHCHECK is run on demand below (`podman healthcheck run`): these hosts have no
  # systemd for podman's health timers (podman logs an error about it; harmless).
  # Locked down as in deploy/k8s: read-only root filesystem (podman adds a tmpfs /tmp), no
  # capabilities, no privilege escalation; only the volume is writable.
  "${P[@]}" run -d --name "$NAME" --network=host -v "$VOL:/var/lib/pliant" \
    --read-only --cap-drop=ALL --security-opt=no-new-privileges \
    -e PLIANT_LISTEN="$ADDR" -e PLIANT_TOKEN="$TOKEN" -e PLIANT_LOG_LEVEL=info \
    "$IID" >>"$TMPD/podman.log" 2>&1 || { cat "$TMPD/podman.log" >&2; die "podman run failed"; }
}
wait_healthy() {  # the image's own HEALTHCHECK (pliant health), up to 60 s
  local i state
  for i in $(seq 1 120); do
    state=$("${P[@]}" inspect --format '{{.State.Status}}' "$NAME" 2>/dev/null || echo gone)
    [ "$state" = running ] || die "container is $state before it became healthy"
    if "${P[@]}" healthcheck run "$NAME" >/dev/null 2>&1; then say "healthy (HEALTHCHECK passed)"; return 0; fi
    sleep 0.5
  done
  die "no healthy HEALTHCHECK within 60 s"
}

# The host side uses the image's own `pliant` (the same Debian 12 libraries are on the host).
"${P[@]}" create --name "$NAME-cli" "$IID" >/dev/null
"${P[@]}" cp "$NAME-cli:/usr/local/bin/pliant" "$TMPD/pliant" && "${P[@]}" rm -v "$NAME-cli" >/dev/null
cli() { PLIANT_ADDRESS=$ADDR PLIANT_TOKEN=$TOKEN "$TMPD/pliant" "$@"; }
json() {  # json EXPR < last JSON line of stdin: print EXPR of it (d = the parsed object)
  python3 -c 'import json,sys; d=json.loads([l for l in sys.stdin if l.strip().startswith(("{","["))][-1]); print(eval(sys.argv[1]))' "$1"
}

timed start start_server
wait_healthy
cli health --address "$ADDR" >/dev/null || die "pliant health from the host failed"

# 7. Two scenes from the host: a realtime one whose frames we stream, and a lockstep one stepped to
#    an exact tick, whose full state we save locally (`snapshot save --out`) to compare after restart.
scene() {  # scene ID FIELD: a field of `scenes get ID --json`
  cli --json scenes get "$1" | json "d['$2']"
}
cli scenes create smoke-rt --mesh beam1 >/dev/null || die "scenes create smoke-rt failed"
cli scenes create smoke-ls --mesh beam1 --mode lockstep >/dev/null || die "scenes create smoke-ls failed"
cli step smoke-ls 25 >/dev/null || die "step smoke-ls 25 failed"
# A model from the image's meshes/ set, found through PLIANT_MODEL_PATH (SOFA liver, 181 vertices).
if [ -n "$(ls -A "$REPO/meshes" 2>/dev/null)" ]; then
  cli scenes create smoke-liver --mesh liver --mode lockstep >/dev/null || die "a scene from meshes/ (liver) failed"
  v=$(scene smoke-liver vertex_count); cli scenes delete smoke-liver >/dev/null
  say "model path: scene from meshes/ 'liver' has $v vertices"
  [ "$v" -gt 0 ] || die "liver scene has no vertices"
fi
timed watch cli --json watch smoke-rt --duration 3 >"$TMPD/watch1.json" || die "watch failed"
frames=$(json "d['frames']" <"$TMPD/watch1.json"); ticks=$(json "d['ticks']" <"$TMPD/watch1.json")
say "streamed from the host: $(tail -n 1 "$TMPD/watch1.json")"
[ "$frames" -gt 0 ] && [ "$ticks" -gt 0 ] || die "watch saw $frames frames, $ticks ticks"
cli --json scenes list >"$TMPD/list1.json" || die "scenes list failed"
n1=$(json "len(d['scenes'])" <"$TMPD/list1.json")
[ "$n1" = 2 ] || die "expected 2 scenes, the server lists $n1"
rt_tick1=$(scene smoke-rt tick); ls_tick1=$(scene smoke-ls tick)
[ "$ls_tick1" = 25 ] || die "smoke-ls is at tick $ls_tick1 after step 25"
cli snapshot save smoke-ls --out "$TMPD/smoke-ls.before" >/dev/null || die "snapshot save --out failed"

# 8. Restart: SIGTERM (podman stop), the server writes its snapshots to the volume; a new start on
#    the same volume restores them.
timed stop "${P[@]}" stop -t 30 "$NAME" >/dev/null 2>>"$TMPD/podman.log"
code=$("${P[@]}" inspect --format '{{.State.ExitCode}}' "$NAME")
[ "$code" = 0 ] || die "server exited with $code on SIGTERM"
"${P[@]}" logs "$NAME" 2>&1 | grep -iE 'snapshot|shut' | tail -3 | sed 's/^/  server: /' >&2 || true
"${P[@]}" run --rm --network=none -v "$VOL:/data:ro" --entrypoint ls "$IID" -lR /data \
  2>/dev/null | sed 's/^/  volume: /' >&2
timed restart "${P[@]}" start "$NAME" >/dev/null 2>>"$TMPD/podman.log"
wait_healthy
cli --json scenes list >"$TMPD/list2.json" || die "scenes list after restart failed"
ids=$(json "' '.join(s['scene_id'] for s in d['scenes'])" <"$TMPD/list2.json")
[ "$ids" = "smoke-ls smoke-rt" ] || die "after the restart the server lists '$ids', not 'smoke-ls smoke-rt'"
ls_tick2=$(scene smoke-ls tick); ls_state=$(scene smoke-ls state); rt_tick2=$(scene smoke-rt tick)
[ "$ls_tick2" = 25 ] || die "smoke-ls came back at tick $ls_tick2, not 25"
[ "$ls_state" = SCENE_STATE_LOCKSTEP ] || die "smoke-ls came back $ls_state"
[ "$rt_tick2" -ge "$rt_tick1" ] || die "smoke-rt came back at tick $rt_tick2 < $rt_tick1 (reset?)"
cli snapshot save smoke-ls --out "$TMPD/smoke-ls.after" >/dev/null || die "snapshot save --out failed"
# Same Snapshot message (pliant.v1.Snapshot, protobuf wire format) except field 12, saved_unix_ns.
python3 - "$TMPD/smoke-ls.before" "$TMPD/smoke-ls.after" <<'PY' || die "smoke-ls's state differs after the restart"
import sys
def fields(path):  # top-level (field number, raw bytes) of a protobuf message, without field 12
    b, i, out = open(path, "rb").read(), 0, []
    def varint():
        nonlocal i
        v = s = 0
        while True:
            c = b[i]; i += 1; v |= (c & 0x7F) << s; s += 7
            if c < 0x80: return v
    while i < len(b):
        start = i; key = varint(); num, wt = key >> 3, key & 7
        if wt == 0: varint()
        elif wt == 1: i += 8
        elif wt == 5: i += 4
        elif wt == 2: n = varint(); i += n
        else: sys.exit(f"unexpected wire type {wt}")
        if num != 12: out.append((num, b[start:i]))
    return out
a, b = fields(sys.argv[1]), fields(sys.argv[2])
if a != b:
    sys.exit("snapshot fields differ: " + str([n for (n, x), (m, y) in zip(a, b) if x != y] or "count"))
print(f"  state: {len(a)} snapshot fields identical (positions, velocities, multipliers, tick, time)", file=sys.stderr)
PY
say "restored from the volume: smoke-ls at tick 25 with identical state, smoke-rt at tick $rt_tick2 (was $rt_tick1)"
cli --json watch smoke-rt --duration 2 >"$TMPD/watch2.json" || die "watch after restart failed"
[ "$(json "d['ticks']" <"$TMPD/watch2.json")" -gt 0 ] || die "smoke-rt does not tick after the restart"
say "streamed after restart: $(tail -n 1 "$TMPD/watch2.json")"

# 9. compose.yaml as users run it (podman-compose; `docker compose` reads the same file): bridge
#    network, published port, named volume; the demo service creates a scene and watches it.
if command -v podman-compose >/dev/null; then
  stop_server() { "${P[@]}" rm -f -v -t 10 "$NAME" >/dev/null 2>&1 || true; }
  stop_server   # frees nothing here (host networking, free port), but halves the CPU load
  printf '[storage]\ndriver = "overlay"\ngraphroot = "%s"\nrunroot = "%s"\n' "$CACHE/storage" "$CACHE/run" \
    > "$TMPD/storage.conf"
  PROJ=pliant-smoke-$$
  WEB_PORT=$(python3 -c 'import socket; s=socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])')
  compose() {
    $SUDO env CONTAINERS_CONF="$CACHE/containers.conf" CONTAINERS_STORAGE_CONF="$TMPD/storage.conf" \
      PLIANT_PORT="$PORT" PLIANT_WEB_PORT="$WEB_PORT" PLIANT_DEMO_SECONDS=3 PLIANT_TOKEN="$TOKEN" \
      podman-compose -p "$PROJ" -f compose.yaml "$@"
  }
  compose_cleanup() {  # like `compose down`, plus the anonymous volume the demo's VOLUME got
    local ids
    ids=$("${P[@]}" ps -aq --filter "label=io.podman.compose.project=$PROJ" 2>/dev/null || true)
    [ -z "$ids" ] || "${P[@]}" rm -f -v -t 10 $ids >/dev/null 2>&1 || true
    "${P[@]}" volume rm -f "${PROJ}_pliant-data" >/dev/null 2>&1 || true
    "${P[@]}" network rm -f "${PROJ}_default" >/dev/null 2>&1 || true
    "${P[@]}" untag localhost/pliant:latest localhost/pliant:latest >/dev/null 2>&1 || true
  }
  trap 'compose_cleanup; cleanup' EXIT
  "${P[@]}" tag "$IID" localhost/pliant:latest   # compose.yaml's image: pliant:latest, no rebuild
  timed compose-up compose up -d >"$TMPD/compose.log" 2>&1 || { cat "$TMPD/compose.log" >&2; die "compose up failed"; }
  for i in $(seq 1 60); do
    st=$("${P[@]}" inspect --format '{{.State.Status}} {{.State.ExitCode}}' "${PROJ}_demo_1" 2>/dev/null || echo missing)
    case $st in exited*|stopped*) break ;; esac; sleep 1   # podman 4.3 says "stopped" at times
  done
  "${P[@]}" logs "${PROJ}_demo_1" >"$TMPD/demo.log" 2>&1 || true
  sed 's/^/  demo: /' "$TMPD/demo.log" | grep -E 'created|running|ticks in' >&2 || true
  [ "${st#* }" = 0 ] && [ "${st% *}" != running ] && grep -q 'created scene demo' "$TMPD/demo.log" && grep -qE '[1-9][0-9]* ticks in' "$TMPD/demo.log" \
    || { cat "$TMPD/demo.log" >&2; die "compose demo client: $st"; }
  PLIANT_ADDRESS=127.0.0.1:$PORT PLIANT_TOKEN=$TOKEN "$TMPD/pliant" scenes get demo >/dev/null \
    || die "the compose server's published port 127.0.0.1:$PORT does not answer"
  # The viewer (service web): its page on the published port.
  page=""
  for i in $(seq 1 30); do
    page=$(python3 -c 'import sys,urllib.request; print(urllib.request.urlopen(sys.argv[1], timeout=2).read().decode())' \
      "http://127.0.0.1:$WEB_PORT/" 2>/dev/null) && break
    sleep 1
  done
  case $page in *"Pliant viewer"*) ;; *) "${P[@]}" logs "${PROJ}_web_1" >&2 || true; die "compose web: no page on 127.0.0.1:$WEB_PORT" ;; esac
  say "compose.yaml: server healthy, demo created and watched a scene, published port answers, viewer page served"
  compose_cleanup; trap cleanup EXIT
else
  say "NOTE: podman-compose not installed: compose.yaml not exercised (apt-get install podman-compose)"
fi

say "PASSED: container smoke test ($(awk -v s="$T0" -v e="$(date +%s.%N)" 'BEGIN{printf "%.0f", e-s}') s; image $(awk -v s="$size" 'BEGIN{printf "%.0f MB", s/1e6}'))"
