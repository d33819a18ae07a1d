"""The deployment files checked without a cluster or a container runtime (docs/deploy.md):

- deploy/haproxy.cfg: `haproxy -c` accepts it (its certificate path pointed at a PEM made here), and
  the settings the HAProxy test runs (test_haproxy.py) are the file's;
- Containerfile: every COPY source exists, the entrypoint is the copied binary, the bundle it serves is
  copied, the port it listens on is the one it exposes; the build context leaves target/ out;
- deploy/kubernetes: readiness and liveness on /healthz, a preStop that drains, a grace period longer
  than the drain delay and timeout, the Service and the HorizontalPodAutoscaler aimed at the
  Deployment, the autoscaler's metric one that /metrics has.

Each check returns its problems as text; the `broken_*` tests show that each one fails on a
deliberately broken file."""
import json
import os
import pathlib
import re
import shutil
import subprocess
import urllib.request

import pytest
import yaml

from conftest import Server
from test_haproxy import haproxy_config, make_pem

ROOT = pathlib.Path(__file__).resolve().parents[3]
K8S = ROOT / "deploy/kubernetes"


# ------------------------------------------------------------------------------------------ HAProxy

# the lines of deploy/haproxy.cfg that make the rolling restart lose nothing; the test's config must
# have them too (addresses, timeouts and check intervals differ)
KEY_HAPROXY = ["mode http", "timeout tunnel", "retries 3", "option redispatch 1",
               "retry-on conn-failure empty-response 503", "option forwardfor", "balance leastconn",
               "option httpchk GET /healthz", "http-check expect status 200", "alpn http/1.1"]


def haproxy_problems(deploy_cfg: str, test_cfg: str):
    def lines(text):
        return [re.sub(r"\s+", " ", l.split("#")[0]).strip() for l in text.splitlines()]
    problems = []
    for key in KEY_HAPROXY:
        if not any(l.startswith(key) or f" {key}" in l for l in lines(deploy_cfg)):
            problems.append(f"deploy/haproxy.cfg lacks `{key}`")
        if not any(l.startswith(key) or f" {key}" in l for l in lines(test_cfg)):
            problems.append(f"the HAProxy test's config lacks `{key}` (deploy/haproxy.cfg has it)")
    return problems


def test_haproxy_cfg_is_valid_and_is_what_the_test_runs(tmp_path):
    deploy_cfg = (ROOT / "deploy/haproxy.cfg").read_text()
    test_cfg = haproxy_config(1, 2, tmp_path / "x.pem", [3, 4, 5])
    assert haproxy_problems(deploy_cfg, test_cfg) == []
    if shutil.which("haproxy") is None:
        if os.environ.get("LIVEGESTURE_REQUIRE_HAPROXY") == "1":
            pytest.fail("haproxy is not installed (scripts/test.sh installs Debian's haproxy)")
        pytest.skip("haproxy is not installed")
    pem, _ = make_pem(tmp_path)
    cfg = tmp_path / "haproxy.cfg"
    cfg.write_text(deploy_cfg.replace("/etc/haproxy/livegesture.pem", str(pem)))
    check = subprocess.run(["haproxy", "-c", "-f", str(cfg)], capture_output=True, text=True)
    assert check.returncode == 0, check.stdout + check.stderr
    # and it refuses a broken one (the check can fail)
    cfg.write_text(deploy_cfg.replace("/etc/haproxy/livegesture.pem", str(pem)).replace("balance leastconn", "balance nosuch"))
    assert subprocess.run(["haproxy", "-c", "-f", str(cfg)], capture_output=True).returncode != 0


def test_broken_haproxy_settings_are_found(tmp_path):
    deploy_cfg = (ROOT / "deploy/haproxy.cfg").read_text()
    test_cfg = haproxy_config(1, 2, tmp_path / "x.pem", [3, 4, 5])
    assert haproxy_problems(deploy_cfg.replace("retry-on", "# retry-on"), test_cfg) == [
        "deploy/haproxy.cfg lacks `retry-on conn-failure empty-response 503`"]
    assert haproxy_problems(deploy_cfg, test_cfg.replace("balance leastconn", "balance roundrobin")) == [
        "the HAProxy test's config lacks `balance leastconn` (deploy/haproxy.cfg has it)"]


# ------------------------------------------------------------------------------------------ Containerfile

def containerfile_problems(text: str, root: pathlib.Path):
    problems = []
    lines = [l.strip() for l in text.splitlines() if l.strip() and not l.strip().startswith("#")]
    stages = [l for l in lines if l.startswith("FROM ")]
    final = lines[lines.index(stages[-1]):]
    copies = {}
    for l in lines:
        if l.startswith("COPY ") and "--from=" not in l:
            *srcs, dst = l.split()[1:]
            for s in srcs:
                if s != "." and not (root / s).exists():
                    problems.append(f"COPY source {s} does not exist")
    for l in final:
        if l.startswith("COPY "):
            *srcs, dst = [w for w in l.split()[1:] if not w.startswith("--")]
            copies[dst] = srcs
    entry = next((l for l in final if l.startswith("ENTRYPOINT ")), None)
    cmd = next((l for l in final if l.startswith("CMD ")), None)
    if entry is None:
        return problems + ["the runtime stage has no ENTRYPOINT"]
    argv = json.loads(entry[len("ENTRYPOINT "):]) + (json.loads(cmd[len("CMD "):]) if cmd else [])
    if argv[0] not in copies:
        problems.append(f"ENTRYPOINT runs {argv[0]}, which no COPY of the runtime stage puts there")
    if "--bundle" in argv:
        b = argv[argv.index("--bundle") + 1]
        if b not in copies:
            problems.append(f"--bundle {b} is not copied into the image")
    port = argv[argv.index("--addr") + 1].rsplit(":", 1)[1] if "--addr" in argv else "8765"
    exposed = [l.split()[1] for l in final if l.startswith("EXPOSE ")]
    if exposed != [port]:
        problems.append(f"EXPOSE {exposed} is not the port serve listens on ({port})")
    if not any(l.startswith("USER ") and not l.split()[1].startswith("0") for l in final):
        problems.append("the runtime stage runs as root (no unprivileged USER)")
    ignore = (root / ".containerignore").read_text().split()
    if "target/" not in ignore and "target" not in ignore:
        problems.append(".containerignore does not leave target/ out of the build context")
    return problems


def test_containerfile_copies_what_exists_and_runs_what_it_copies():
    assert containerfile_problems((ROOT / "Containerfile").read_text(), ROOT) == []


def test_broken_containerfiles_are_found():
    text = (ROOT / "Containerfile").read_text()
    assert containerfile_problems(text.replace("COPY models/diffsheg", "COPY models/nosuch"), ROOT) == [
        "COPY source models/nosuch does not exist"]
    assert containerfile_problems(text.replace("EXPOSE 8765", "EXPOSE 8080"), ROOT) == [
        "EXPOSE ['8080'] is not the port serve listens on (8765)"]
    assert containerfile_problems(text.replace("/opt/livegesture/models/default\",", "/opt/x\","), ROOT) == [
        "--bundle /opt/x is not copied into the image"]
    assert containerfile_problems(text.replace("/usr/local/bin/livegesture\", \"serve", "/bin/livegesture\", \"serve"), ROOT) == [
        "ENTRYPOINT runs /bin/livegesture, which no COPY of the runtime stage puts there"]


# ------------------------------------------------------------------------------------------ Kubernetes

def load_k8s():
    docs = {}
    for f in sorted(K8S.glob("*.yaml")):
        for d in yaml.safe_load_all(f.read_text()):
            docs[d["kind"]] = d
    return docs


def flag(args, name, default=None):
    for a in args:
        if a.startswith(f"--{name}="):
            return a.split("=", 1)[1]
    return default


def k8s_problems(docs, metric_names):
    problems = []
    dep, svc, hpa = docs.get("Deployment"), docs.get("Service"), docs.get("HorizontalPodAutoscaler")
    if not (dep and svc and hpa):
        return [f"deploy/kubernetes has {sorted(docs)}, expected a Deployment, a Service and a HorizontalPodAutoscaler"]
    pod = dep["spec"]["template"]["spec"]
    c = pod["containers"][0]
    ports = {p["name"]: p["containerPort"] for p in c.get("ports", [])}
    for probe in ("readinessProbe", "livenessProbe"):
        get = (c.get(probe) or {}).get("httpGet") or {}
        if get.get("path") != "/healthz" or get.get("port") not in list(ports) + list(ports.values()):
            problems.append(f"{probe} is not an HTTP GET of /healthz on the container's port")
    pre = " ".join(((c.get("lifecycle") or {}).get("preStop") or {}).get("exec", {}).get("command", []))
    if "kill -TERM 1" not in pre or "while kill -0 1" not in pre:
        problems.append("preStop does not start the drain (SIGTERM to the server) and wait for it to end")
    args = c.get("args", [])
    # a pause before the drain (`sleep N;` first), not the wait loop's `sleep 1`
    m = re.search(r"-c sleep (\d+(?:\.\d+)?);", pre)
    pause = float(m.group(1)) if m else 0.0
    drain = pause + float(flag(args, "drain-delay", 0)) + float(flag(args, "drain-timeout", 10))
    grace = pod.get("terminationGracePeriodSeconds", 30)
    if not grace > drain:
        problems.append(f"terminationGracePeriodSeconds {grace} is not longer than the preStop's pause + --drain-delay + --drain-timeout ({drain:g} s)")
    labels = dep["spec"]["template"]["metadata"]["labels"]
    if any(labels.get(k) != v for k, v in svc["spec"]["selector"].items()):
        problems.append(f"the Service's selector {svc['spec']['selector']} does not select the pods {labels}")
    for p in svc["spec"]["ports"]:
        if p["targetPort"] not in list(ports) + list(ports.values()):
            problems.append(f"the Service's targetPort {p['targetPort']} is not a container port")
    ref = hpa["spec"]["scaleTargetRef"]
    if (ref["kind"], ref["name"]) != ("Deployment", dep["metadata"]["name"]):
        problems.append(f"the autoscaler scales {ref['kind']}/{ref['name']}, not the Deployment")
    for m in hpa["spec"]["metrics"]:
        name = m.get("pods", {}).get("metric", {}).get("name")
        if name not in metric_names:
            problems.append(f"the autoscaler's metric {name} is not in /metrics")
        target = float(m["pods"]["target"]["averageValue"])
        cap = float(flag(args, "max-sessions", 64))
        if not 0 < target < cap:
            problems.append(f"the autoscaler's target {target:g} sessions per pod is not below --max-sessions {cap:g}")
    return problems


@pytest.fixture(scope="module")
def metric_names(binary, bundle):
    s = Server(binary, bundle)
    try:
        with urllib.request.urlopen(f"http://{s.addr}/metrics", timeout=10) as r:
            text = r.read().decode()
    finally:
        code, log = s.stop()
    assert code == 0, log
    return set(re.findall(r"^# TYPE (\S+) ", text, re.M))


def test_kubernetes_manifests_probe_drain_and_scale_on_sessions(metric_names):
    assert "livegesture_sessions_active" in metric_names
    assert k8s_problems(load_k8s(), metric_names) == []


def test_broken_kubernetes_manifests_are_found(metric_names):
    def broken(edit):
        docs = load_k8s()
        edit(docs)
        return k8s_problems(docs, metric_names)

    def c(d):
        return d["Deployment"]["spec"]["template"]["spec"]["containers"][0]
    assert broken(lambda d: c(d)["readinessProbe"]["httpGet"].update(path="/")) == [
        "readinessProbe is not an HTTP GET of /healthz on the container's port"]
    assert broken(lambda d: c(d)["lifecycle"]["preStop"]["exec"].update(command=["sleep", "5"])) == [
        "preStop does not start the drain (SIGTERM to the server) and wait for it to end"]
    assert broken(lambda d: d["Deployment"]["spec"]["template"]["spec"].update(terminationGracePeriodSeconds=60)) == [
        "terminationGracePeriodSeconds 60 is not longer than the preStop's pause + --drain-delay + --drain-timeout (75 s)"]
    assert broken(lambda d: d["Service"]["spec"].update(selector={"app": "other"})) != []
    assert broken(lambda d: d["HorizontalPodAutoscaler"]["spec"]["metrics"][0]["pods"]["metric"].update(
        name="livegesture_sessions")) == ["the autoscaler's metric livegesture_sessions is not in /metrics"]
    assert broken(lambda d: d.pop("Service")) != []
