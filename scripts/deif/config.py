"""The config, as the C++ parser reads it: one parser, one verdict, the same line numbers.

deif_config resolves a file plus `--set key=value` overrides into the effective config (JSON
or canonical YAML) or refuses it with one line `file:line: key 'k': reason` and exit 2.
"""
import json
import subprocess

from . import paths


class ConfigRefused(Exception):
    """The C++ parser refused the config; str() is its one-line reason."""


def _run(config_path, overrides, fmt):
    cmd = [paths.executable("deif_config"), "--config", config_path]
    for o in overrides:
        cmd += ["--set", o]
    cmd += ["--print", fmt]
    proc = subprocess.run(cmd, capture_output=True, text=True, errors="replace")
    if proc.returncode != 0:
        msg = (proc.stderr.strip() or proc.stdout.strip()).splitlines()
        line = msg[-1] if msg else f"deif_config exited {proc.returncode}"
        raise ConfigRefused(line.removeprefix("deif_config: error: "))
    return proc.stdout


def resolve(config_path, overrides=()):
    """The effective config as a dict (raises ConfigRefused)."""
    return json.loads(_run(config_path, list(overrides), "json"))


def canonical_yaml(config_path, overrides=()):
    """The effective config as YAML every process can read back identically."""
    return _run(config_path, list(overrides), "yaml")


def flow(value):
    """A Python value as a YAML flow value for --set (JSON is YAML)."""
    return json.dumps(value)
