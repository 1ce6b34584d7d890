"""Generates the gRPC stubs (posewarp/v1) from the repository's proto as the package is built, with the protoc and
grpc_python_plugin of Debian's protobuf-compiler-grpc, or else grpc_tools (python3-grpc-tools or grpcio-tools)."""
import os
import shutil
import subprocess
import sys

from setuptools import setup
from setuptools.command.build_py import build_py

HERE = os.path.dirname(os.path.abspath(__file__))
PROTO_ROOT = os.environ.get("POSEWARP_PROTO_ROOT", os.path.join(HERE, "..", "..", "proto"))
PROTO = os.path.join("posewarp", "v1", "posewarp.proto")


def protoc_command(out):
    protoc, plugin = shutil.which("protoc"), shutil.which("grpc_python_plugin")
    if protoc and plugin:
        return [protoc, f"--plugin=protoc-gen-grpc_python={plugin}", "--grpc_python_out", out]
    for python in (sys.executable, "/usr/bin/python3"):
        if subprocess.run([python, "-c", "import grpc_tools.protoc"], capture_output=True).returncode == 0:
            return [python, "-m", "grpc_tools.protoc", "--grpc_python_out", out]
    sys.exit("posewarp: the stubs need protoc and grpc_python_plugin (Debian: apt-get install "
             "protobuf-compiler-grpc) or grpc_tools (python3-grpc-tools, or pip install grpcio-tools)")


class BuildWithStubs(build_py):
    def run(self):
        if not os.path.exists(os.path.join(PROTO_ROOT, PROTO)):
            sys.exit(f"posewarp: {os.path.join(PROTO_ROOT, PROTO)} not found; build from the repository's "
                     "clients/python, or set POSEWARP_PROTO_ROOT to its proto/ folder")
        out = os.path.join(self.build_lib)
        os.makedirs(os.path.join(out, "posewarp", "v1"), exist_ok=True)
        command = protoc_command(out) + ["-I", PROTO_ROOT, "--python_out", out, os.path.join(PROTO_ROOT, PROTO)]
        subprocess.run(command, check=True)
        open(os.path.join(out, "posewarp", "v1", "__init__.py"), "a").close()
        super().run()


setup(cmdclass={"build_py": BuildWithStubs})
