#!/usr/bin/python3
# SPDX-License-Identifier: Apache-2.0
"""Checks Pliant's deployment files without kubectl or docker.

    validate_manifests.py [--dockerfile docker/Dockerfile] [--compose compose.yaml] K8S.yaml...
    validate_manifests.py --self-test --dockerfile ... --compose ... K8S.yaml...

Kubernetes manifests: every document parses, has apiVersion/kind/metadata.name, the apiVersion fits
the kind, and per kind the fields a cluster would demand are present. Across documents: selectors
match the pod template's labels, Services select some workload and target one of its ports, probe
ports are container ports, volume mounts name declared volumes (or volumeClaimTemplates), claims
name declared PersistentVolumeClaims, a StatefulSet's serviceName is a declared headless Service.
Against the image (docker/Dockerfile): the server container exposes the image's EXPOSEd port, has
gRPC readiness and liveness probes on it, and mounts a volume on the image's VOLUME (snapshots).
compose.yaml: services, healthcheck, volumes and depends_on are consistent.

--self-test breaks the given files in known ways and fails unless each break is reported.
Needs python3-yaml (Debian's; call /usr/bin/python3). Exit status 0 when everything holds.
"""
import argparse
import copy
import re
import sys

import yaml

API_VERSIONS = {
    "Deployment": "apps/v1",
    "StatefulSet": "apps/v1",
    "Service": "v1",
    "PersistentVolumeClaim": "v1",
    "ConfigMap": "v1",
    "Secret": "v1",
    "PodDisruptionBudget": "policy/v1",
}
WORKLOADS = ("Deployment", "StatefulSet")
QUANTITY = re.compile(r"^[0-9]+(\.[0-9]+)?(Ki|Mi|Gi|Ti|Pi|Ei|k|M|G|T|P|E|m)?$")
DNS_LABEL = re.compile(r"^[a-z0-9]([-a-z0-9]*[a-z0-9])?$")


class Report:
    def __init__(self):
        self.errors = []

    def err(self, where, msg):
        self.errors.append(f"{where}: {msg}")


def get(obj, path, default=None):
    """get(obj, 'a.b.c'): nested dict lookup, default when any step is missing or not a dict."""
    for key in path.split("."):
        if not isinstance(obj, dict) or key not in obj:
            return default
        obj = obj[key]
    return obj


def require(rep, where, obj, path, typ=None):
    value = get(obj, path)
    if value is None or value == "" or value == [] or value == {}:
        rep.err(where, f"missing {path}")
        return None
    if typ is not None and not isinstance(value, typ):
        rep.err(where, f"{path} should be {typ.__name__ if isinstance(typ, type) else typ}")
        return None
    return value


# ---- the image ---------------------------------------------------------------------------------

def read_dockerfile(path):
    """EXPOSEd ports and VOLUMEs of the last stage of a Dockerfile."""
    ports, volumes = set(), set()
    text = open(path).read().replace("\\\n", " ")
    for line in text.splitlines():
        words = line.strip().split(None, 1)
        if not words:
            continue
        op = words[0].upper()
        rest = words[1] if len(words) > 1 else ""
        if op == "FROM":
            ports, volumes = set(), set()
        elif op == "EXPOSE":
            ports |= {int(p.split("/")[0]) for p in rest.split()}
        elif op == "VOLUME":
            rest = rest.strip()
            volumes |= set(yaml.safe_load(rest)) if rest.startswith("[") else set(rest.split())
    return ports, volumes


# ---- Kubernetes ---------------------------------------------------------------------------------

def check_pod_spec(rep, where, pod, claim_templates, pvcs, image):
    containers = require(rep, where, pod, "containers", list) or []
    volumes = {}
    for i, vol in enumerate(get(pod, "volumes", []) or []):
        name = get(vol, "name")
        if not name:
            rep.err(where, f"volumes[{i}] has no name")
            continue
        if name in volumes:
            rep.err(where, f"volume {name} declared twice")
        volumes[name] = vol
        claim = get(vol, "persistentVolumeClaim.claimName")
        if "persistentVolumeClaim" in vol and claim not in pvcs:
            rep.err(where, f"volume {name} claims PersistentVolumeClaim {claim!r}, not declared")
    mountable = set(volumes) | set(claim_templates)
    ports_all = {}
    for c in containers:
        cw = f"{where} container {get(c, 'name', '?')}"
        require(rep, cw, c, "name", str)
        require(rep, cw, c, "image", str)
        ports = {}
        for j, p in enumerate(get(c, "ports", []) or []):
            num = get(p, "containerPort")
            if not isinstance(num, int) or not 0 < num < 65536:
                rep.err(cw, f"ports[{j}].containerPort should be a port number, is {num!r}")
                continue
            ports[num] = num
            if get(p, "name"):
                ports[p["name"]] = num
        ports_all.update(ports)
        mounts = {}
        for j, m in enumerate(get(c, "volumeMounts", []) or []):
            name, path = get(m, "name"), get(m, "mountPath")
            if not name or not path:
                rep.err(cw, f"volumeMounts[{j}] needs name and mountPath")
                continue
            if name not in mountable:
                rep.err(cw, f"volumeMount {name} refers to no declared volume or volumeClaimTemplate")
            mounts[path] = name
        for k, e in enumerate(get(c, "env", []) or []):
            if not get(e, "name"):
                rep.err(cw, f"env[{k}] has no name")
            if "value" in e and not isinstance(e["value"], str):
                rep.err(cw, f"env {get(e, 'name')} value must be a string (quote it)")
            ref = get(e, "valueFrom.secretKeyRef") or get(e, "valueFrom.configMapKeyRef")
            if "valueFrom" in e and not (ref and get(ref, "name") and get(ref, "key")):
                rep.err(cw, f"env {get(e, 'name')} valueFrom needs a key reference with name and key")
        for probe_name in ("startupProbe", "readinessProbe", "livenessProbe"):
            probe = get(c, probe_name)
            if probe is None:
                continue
            handlers = [h for h in ("grpc", "tcpSocket", "httpGet", "exec") if h in probe]
            if len(handlers) != 1:
                rep.err(cw, f"{probe_name} needs exactly one of grpc/tcpSocket/httpGet/exec")
                continue
            if handlers[0] == "exec":
                continue
            port = get(probe, handlers[0] + ".port")
            if handlers[0] == "grpc" and not isinstance(port, int):
                rep.err(cw, f"{probe_name}.grpc.port must be a number (Kubernetes allows no names)")
            elif port not in ports:
                rep.err(cw, f"{probe_name} port {port!r} is not a port of the container")
        if image is not None and c is containers[0]:
            exposed, image_volumes = image
            served = exposed & set(ports.values())
            if not served:
                rep.err(cw, f"exposes none of the image's ports {sorted(exposed)}")
            for probe_name in ("readinessProbe", "livenessProbe"):
                if get(c, probe_name + ".grpc.port") not in served:
                    rep.err(cw, f"{probe_name} should ask the gRPC health service on {sorted(exposed)}")
            for path in image_volumes:
                if path not in mounts:
                    rep.err(cw, f"no volume mounted on the image's VOLUME {path} (snapshots are lost)")
    return ports_all


def check_scrape_annotations(rep, where, annotations, pod, ports):
    """Prometheus' pod annotations name a container port that the server's --metrics-listen serves."""
    if "prometheus.io/scrape" not in annotations:
        return
    if annotations["prometheus.io/scrape"] != "true":
        rep.err(where, "annotation prometheus.io/scrape must be the string \"true\"")
    port = annotations.get("prometheus.io/port")
    if not isinstance(port, str) or not port.isdigit():
        rep.err(where, f"annotation prometheus.io/port must be a quoted port number, is {port!r}")
        return
    if int(port) not in ports:
        rep.err(where, f"annotation prometheus.io/port {port} is not a container port")
    containers = get(pod, "containers", []) or []
    env = {get(e, "name"): get(e, "value") for e in (get(containers[0], "env", []) or [])} if containers else {}
    listen = env.get("PLIANT_METRICS_LISTEN")
    if listen is None:
        rep.err(where, "scraped on port " + port + " but the server sets no PLIANT_METRICS_LISTEN")
    elif str(listen).rsplit(":", 1)[-1] != port:
        rep.err(where, f"PLIANT_METRICS_LISTEN {listen} does not listen on the scraped port {port}")


def check_k8s(docs, image, rep):
    by_kind = {}
    for where, d in docs:
        if not isinstance(d, dict):
            rep.err(where, "document is not a mapping")
            continue
        kind, api = get(d, "kind"), get(d, "apiVersion")
        name = get(d, "metadata.name")
        if not kind or not api or not name:
            rep.err(where, "needs apiVersion, kind and metadata.name")
            continue
        if not DNS_LABEL.match(str(name)) or len(name) > 63:
            rep.err(where, f"metadata.name {name!r} is not a DNS label")
        if kind not in API_VERSIONS:
            rep.err(where, f"unexpected kind {kind} (the validator knows {sorted(API_VERSIONS)})")
        elif api != API_VERSIONS[kind]:
            rep.err(where, f"{kind} is apiVersion {API_VERSIONS[kind]}, not {api}")
        key = (kind, name)
        if key in by_kind:
            rep.err(where, f"{kind} {name} declared twice")
        by_kind[key] = (f"{where} ({kind} {name})", d)

    pvcs = set()
    for (kind, name), (where, d) in by_kind.items():
        if kind != "PersistentVolumeClaim":
            continue
        pvcs.add(name)
        check_claim_spec(rep, where, get(d, "spec"))

    workloads = {}  # name -> (labels, ports)
    for (kind, name), (where, d) in by_kind.items():
        if kind not in WORKLOADS:
            continue
        spec = require(rep, where, d, "spec", dict) or {}
        match = require(rep, where, spec, "selector.matchLabels", dict) or {}
        labels = require(rep, where, spec, "template.metadata.labels", dict) or {}
        for k, v in match.items():
            if labels.get(k) != v:
                rep.err(where, f"selector {k}={v} does not match the pod template's labels")
        replicas = get(spec, "replicas", 1)
        if not isinstance(replicas, int) or replicas < 0:
            rep.err(where, "replicas must be a non-negative number")
        templates = {}
        if kind == "StatefulSet":
            svc = require(rep, where, spec, "serviceName", str)
            if svc and ("Service", svc) not in by_kind:
                rep.err(where, f"serviceName {svc} is not a declared Service")
            elif svc and get(by_kind[("Service", svc)][1], "spec.clusterIP") != "None":
                rep.err(where, f"serviceName {svc} should be a headless Service (clusterIP: None)")
            for i, t in enumerate(get(spec, "volumeClaimTemplates", []) or []):
                tname = get(t, "metadata.name")
                if not tname:
                    rep.err(where, f"volumeClaimTemplates[{i}] has no metadata.name")
                    continue
                templates[tname] = t
                check_claim_spec(rep, f"{where} volumeClaimTemplate {tname}", get(t, "spec"))
        pod = require(rep, where, spec, "template.spec", dict) or {}
        ports = check_pod_spec(rep, where, pod, templates, pvcs, image)
        workloads[name] = (labels, ports)
        check_scrape_annotations(rep, where, get(spec, "template.metadata.annotations", {}) or {}, pod, ports)
        if kind == "Deployment" and get(spec, "strategy.type") != "Recreate" and any(
                get(v, "persistentVolumeClaim.claimName") for v in get(pod, "volumes", []) or []):
            # A ReadWriteOnce claim cannot be attached to the old and the new pod at once.
            rep.err(where, "a Deployment with a persistent volume should use strategy Recreate")

    for (kind, name), (where, d) in by_kind.items():
        if kind == "PodDisruptionBudget":
            match = require(rep, where, d, "spec.selector.matchLabels", dict) or {}
            if match and not any(all(labels.get(k) == v for k, v in match.items())
                                 for labels, _ in workloads.values()):
                rep.err(where, f"selector {match} matches no workload's pod labels")

    for (kind, name), (where, d) in by_kind.items():
        if kind != "Service":
            continue
        selector = require(rep, where, d, "spec.selector", dict) or {}
        targets = [w for w, (labels, _) in workloads.items()
                   if selector and all(labels.get(k) == v for k, v in selector.items())]
        if selector and not targets:
            rep.err(where, f"selector {selector} matches no workload's pod labels")
        for i, p in enumerate(require(rep, where, d, "spec.ports", list) or []):
            port = get(p, "port")
            if not isinstance(port, int) or not 0 < port < 65536:
                rep.err(where, f"ports[{i}].port should be a port number")
                continue
            target = get(p, "targetPort", port)
            for w in targets:
                if target not in workloads[w][1]:
                    rep.err(where, f"targetPort {target!r} is not a container port of {w}")
    if not workloads:
        rep.err("manifests", "no Deployment or StatefulSet")


def check_claim_spec(rep, where, spec):
    modes = require(rep, where, spec, "accessModes", list) or []
    for m in modes:
        if m not in ("ReadWriteOnce", "ReadOnlyMany", "ReadWriteMany", "ReadWriteOncePod"):
            rep.err(where, f"unknown access mode {m}")
    size = require(rep, where, spec, "resources.requests.storage")
    if size is not None and not QUANTITY.match(str(size)):
        rep.err(where, f"storage {size!r} is not a quantity")


# ---- compose ----------------------------------------------------------------------------------

def check_compose(doc, image, rep):
    where = "compose"
    services = require(rep, where, doc, "services", dict) or {}
    declared_volumes = set((get(doc, "volumes") or {}).keys())
    exposed, image_volumes = image if image else (set(), set())
    healthchecked = False
    for name, svc in services.items():
        sw = f"compose service {name}"
        if not isinstance(svc, dict) or not (get(svc, "image") or get(svc, "build")):
            rep.err(sw, "needs image or build")
            continue
        if get(svc, "healthcheck.test"):
            healthchecked = True
        for v in get(svc, "volumes", []) or []:
            src = v.split(":")[0] if isinstance(v, str) else get(v, "source")
            if src and not src.startswith((".", "/", "~")) and src not in declared_volumes:
                rep.err(sw, f"volume {src} is not declared under top-level volumes")
        deps = get(svc, "depends_on", []) or []
        for dep in (deps if isinstance(deps, list) else deps.keys()):
            if dep not in services:
                rep.err(sw, f"depends_on {dep}: no such service")
            elif isinstance(deps, dict) and get(deps[dep], "condition") == "service_healthy" \
                    and not get(services[dep], "healthcheck.test"):
                rep.err(sw, f"waits for {dep} to be healthy but {dep} has no healthcheck")
        for p in get(svc, "ports", []) or []:
            inner = str(p).split(":")[-1].split("/")[0]
            if exposed and int(inner) not in exposed:
                rep.err(sw, f"publishes container port {inner}, the image exposes {sorted(exposed)}")
        mounts = [str(v).split(":")[1] for v in get(svc, "volumes", []) or [] if ":" in str(v)]
        # The server (the image's own entrypoint) keeps its state on a volume; a service that
        # runs another program of the image (pliant-web) has none to keep.
        runs_server = not get(svc, "entrypoint")
        if get(svc, "ports") and runs_server and image_volumes and not set(image_volumes) & set(mounts):
            rep.err(sw, f"server has no named volume on {sorted(image_volumes)}")
    if services and not healthchecked:
        rep.err(where, "no service has a healthcheck")


# ---- driver ------------------------------------------------------------------------------------

def load(paths):
    docs = []
    for path in paths:
        with open(path) as f:
            for i, d in enumerate(yaml.safe_load_all(f)):
                if d is not None:
                    docs.append((f"{path}#{i}", d))
    return docs


def validate(k8s_docs, compose_doc, image):
    rep = Report()
    by_file = {}
    for where, d in k8s_docs:  # each file is one self-contained deployment
        by_file.setdefault(where.split("#")[0], []).append((where, d))
    for docs in by_file.values():
        check_k8s(docs, image, rep)
    if compose_doc is not None:
        check_compose(compose_doc, image, rep)
    return rep.errors


def find(docs, kind, near=None):
    """First document of KIND (in the same file as the first document of kind NEAR)."""
    files = [w.split("#")[0] for w, d in docs if d.get("kind") == near] if near else None
    return next(d for w, d in docs if isinstance(d, dict) and d.get("kind") == kind
                and (files is None or w.split("#")[0] == files[0]))


def self_test(k8s_docs, compose_doc, image):
    """Each break must be reported; the unbroken files must pass."""
    def pod(docs, kind="Deployment"):
        return find(docs, kind)["spec"]["template"]["spec"]

    def server(docs, kind="Deployment"):
        return pod(docs, kind)["containers"][0]

    def svc(d):
        return find(d, "Service")["spec"]

    # name: (a phrase the report must contain, the break)
    breaks = {
        "missing metadata.name": ("needs apiVersion, kind and metadata.name",
            lambda d, c: find(d, "Service")["metadata"].pop("name")),
        "wrong apiVersion": ("is apiVersion apps/v1",
            lambda d, c: find(d, "Deployment").update(apiVersion="v1")),
        "selector/labels mismatch": ("does not match the pod template",
            lambda d, c: find(d, "Deployment")["spec"]["selector"]["matchLabels"]
            .update({"app.kubernetes.io/component": "other"})),
        "service selects nothing": ("matches no workload",
            lambda d, c: svc(d)["selector"].update({"app.kubernetes.io/name": "nothing"})),
        "service targetPort wrong": ("targetPort 'http' is not a container port",
            lambda d, c: svc(d)["ports"][0].update(targetPort="http")),
        "liveness probe on another port": ("livenessProbe port 8080 is not a port",
            lambda d, c: server(d)["livenessProbe"]["grpc"].update(port=8080)),
        "readiness probe missing": ("readinessProbe should ask the gRPC health service",
            lambda d, c: server(d).pop("readinessProbe")),
        "container port not the image's": ("exposes none of the image's ports",
            lambda d, c: [p.update(containerPort=9999) for p in server(d)["ports"]]),
        "mount of undeclared volume": ("volumeMount nope refers to no declared volume",
            lambda d, c: server(d)["volumeMounts"][0].update(name="nope")),
        "claim of undeclared PVC": ("claims PersistentVolumeClaim 'nope', not declared",
            lambda d, c: pod(d)["volumes"][0]["persistentVolumeClaim"].update(claimName="nope")),
        "no volume on /var/lib/pliant": ("no volume mounted on the image's VOLUME",
            lambda d, c: server(d).pop("volumeMounts")),
        "PVC without storage": ("missing resources.requests.storage",
            lambda d, c: find(d, "PersistentVolumeClaim")["spec"].pop("resources")),
        "PVC bad quantity": ("is not a quantity",
            lambda d, c: find(d, "PersistentVolumeClaim")["spec"]["resources"]["requests"]
            .update(storage="lots")),
        "container without image": ("missing image",
            lambda d, c: server(d).pop("image")),
        "unquoted env number": ("value must be a string",
            lambda d, c: server(d)["env"].append({"name": "X", "value": 3})),
        "statefulset serviceName unknown": ("serviceName nope is not a declared Service",
            lambda d, c: find(d, "StatefulSet")["spec"].update(serviceName="nope")),
        "statefulset service not headless": ("should be a headless Service",
            lambda d, c: find(d, "Service", near="StatefulSet")["spec"].pop("clusterIP")),
        "deployment rolling update with a volume": ("should use strategy Recreate",
            lambda d, c: find(d, "Deployment")["spec"].pop("strategy")),
        "PDB selects nothing": ("PodDisruptionBudget pliant): selector",
            lambda d, c: find(d, "PodDisruptionBudget")["spec"]["selector"]["matchLabels"]
            .update({"app.kubernetes.io/name": "nothing"})),
        "statefulset mount of unknown claim template": ("volumeMount nope refers to no",
            lambda d, c: server(d, "StatefulSet")["volumeMounts"][0].update(name="nope")),
        "scrape port not a container port": ("annotation prometheus.io/port 9999 is not a container port",
            lambda d, c: find(d, "Deployment")["spec"]["template"]["metadata"]["annotations"]
            .update({"prometheus.io/port": "9999"})),
        "metrics not listened on": ("sets no PLIANT_METRICS_LISTEN",
            lambda d, c: server(d).update(env=[e for e in server(d)["env"] if e["name"] != "PLIANT_METRICS_LISTEN"])),
        "compose undeclared volume": ("is not declared under top-level volumes",
            lambda d, c: c.pop("volumes")),
        "compose depends on unknown service": ("depends_on nope: no such service",
            lambda d, c: next(s for s in c["services"].values() if s.get("depends_on"))
            .update(depends_on={"nope": {"condition": "service_started"}})),
        "compose server without healthcheck": ("has no healthcheck",
            lambda d, c: [s.pop("healthcheck", None) for s in c["services"].values()]),
        "compose publishes another port": ("publishes container port 9999",
            lambda d, c: next(s for s in c["services"].values() if s.get("ports"))
            .update(ports=["9999:9999"])),
    }
    failures = []
    baseline = validate(k8s_docs, compose_doc, image)
    if baseline:
        failures.append("the unbroken files fail:\n  " + "\n  ".join(baseline))
    for name, (expected, brk) in breaks.items():
        docs, comp = copy.deepcopy(k8s_docs), copy.deepcopy(compose_doc)
        try:
            brk(docs, comp)
        except (StopIteration, KeyError, IndexError, TypeError, AttributeError) as e:
            failures.append(f"break '{name}' does not apply to these files ({e!r})")
            continue
        errors = validate(docs, comp, image)
        hits = [e for e in errors if expected in e]
        print(f"{'ok    ' if hits else 'MISSED'} {name}: {hits[0] if hits else errors or 'no error'}")
        if not hits:
            failures.append(f"break '{name}' was not reported as '{expected}'")
    return failures


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("manifests", nargs="*", help="Kubernetes YAML files (one deployment each)")
    ap.add_argument("--dockerfile", help="check manifests against this image's EXPOSE and VOLUME")
    ap.add_argument("--compose", help="a compose.yaml to check")
    ap.add_argument("--self-test", action="store_true", help="check that breaks are reported")
    args = ap.parse_args()
    try:
        image = read_dockerfile(args.dockerfile) if args.dockerfile else None
        k8s = load(args.manifests)
        compose = load([args.compose])[0][1] if args.compose else None
    except (OSError, yaml.YAMLError, ValueError) as e:
        print(f"FAIL: {e}")
        return 1
    if args.self_test:
        failures = self_test(k8s, compose, image)
        for f in failures:
            print(f"FAIL: {f}")
        print(f"self-test: {'FAILED' if failures else 'passed'}")
        return 1 if failures else 0
    errors = validate(k8s, compose, image)
    for e in errors:
        print(f"FAIL: {e}")
    n = len(k8s) + (compose is not None)
    print(f"{n} documents checked: {'FAILED, %d problems' % len(errors) if errors else 'valid'}")
    return 1 if errors else 0


if __name__ == "__main__":
    sys.exit(main())
