#!/usr/bin/python3
"""docker/compose.yaml read by a YAML parser (PyYAML, Debian's python3-yaml) and checked against the repository:
every file it mounts or builds from exists, every named volume, secret and dependency it uses is declared, each
secret is documented in docker/secrets/README.md, ports are published on loopback only, the nginx template's
variables are all given, and every flag the posewarp services pass (on the command line and in config/server.json)
is one posewarp-server --help lists. Usage: compose_check.py REPOSITORY POSEWARP_SERVER"""
import json
import os
import re
import subprocess
import sys

import yaml

root, server = sys.argv[1], sys.argv[2]
here = os.path.join(root, "docker")
with open(os.path.join(here, "compose.yaml")) as f:
    compose = yaml.safe_load(f)  # anchors and merge keys (<<) resolved
problems = []


def check(condition, message):
    if not condition:
        problems.append(message)


unknown = set(compose) - {"services", "secrets", "volumes", "networks", "configs"}
check(all(key.startswith("x-") for key in unknown), f"unknown top-level keys {sorted(unknown)}")
services = compose.get("services", {})
volumes, secrets = compose.get("volumes", {}) or {}, compose.get("secrets", {}) or {}
check({"posewarp-1", "posewarp-2", "nginx", "db"} <= set(services), f"services are {sorted(services)}")
with open(os.path.join(here, "secrets", "README.md")) as f:
    secrets_readme = f.read()
for name, secret in secrets.items():
    path = os.path.normpath(os.path.join(here, secret["file"]))
    check(path.startswith(os.path.join(here, "secrets") + os.sep), f"secret {name} is not under docker/secrets/")
    check(f"`{os.path.basename(path)}`" in secrets_readme, f"secret {name} is not described in docker/secrets/README.md")
help_text = subprocess.run([server, "--help"], capture_output=True, text=True, check=True).stdout
server_flags = set(re.findall(r"--([a-z][a-z0-9-]*)", help_text))

for name, service in services.items():
    where = f"service {name}"
    check("image" in service or "build" in service, f"{where} has neither image nor build")
    if "build" in service:
        context = os.path.normpath(os.path.join(here, service["build"]["context"]))
        check(os.path.isfile(os.path.join(context, service["build"]["dockerfile"])), f"{where}: no Dockerfile")
    for volume in service.get("volumes", []):
        source = volume.split(":")[0]
        if source.startswith("."):
            check(os.path.exists(os.path.join(here, source)), f"{where} mounts {source}, which does not exist")
        else:
            check(source in volumes, f"{where} uses volume {source}, which is not declared")
    for secret in service.get("secrets", []):
        secret_name = secret if isinstance(secret, str) else secret["source"]
        check(secret_name in secrets, f"{where} uses secret {secret_name}, which is not declared")
    depends = service.get("depends_on", [])
    for other, how in (depends.items() if isinstance(depends, dict) else ((d, {}) for d in depends)):
        check(other in services, f"{where} depends on {other}, which is not a service")
        if how.get("condition") == "service_healthy":
            check("healthcheck" in services.get(other, {}), f"{where} waits for {other} to be healthy: no healthcheck")
    for port in service.get("ports", []):
        check(str(port).startswith("127.0.0.1:"), f"{where} publishes {port} beyond loopback")
    if name.startswith("posewarp-"):
        flags = [arg[2:].split("=")[0] for arg in service.get("command", []) if arg.startswith("--")]
        config = next(v.split(":")[0] for v in service["volumes"] if v.endswith("server.json:ro"))
        with open(os.path.join(here, config)) as f:
            flags += list(json.load(f))
        for flag in flags:
            check(flag in server_flags, f"{where} gives --{flag}, which posewarp-server --help does not list")
    if name == "nginx":
        template = next(v.split(":")[0] for v in service["volumes"] if v.split(":")[0].endswith(".template"))
        with open(os.path.join(here, template)) as f:
            wanted = set(re.findall(r"\$\{([A-Z_0-9]+)\}", f.read()))
        check(wanted <= set(service.get("environment", {})),
              f"{where}: the template's {sorted(wanted - set(service.get('environment', {})))} are not given")

if problems:
    print("docker/compose.yaml:\n  " + "\n  ".join(problems))
    sys.exit(1)
print(f"docker/compose.yaml: {len(services)} services, {len(volumes)} volumes, {len(secrets)} secrets checked")
