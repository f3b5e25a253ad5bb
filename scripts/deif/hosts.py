"""Several hosts on one machine: network namespaces on one bridge (docs/RUNNING.md).

Host i (1..K) is the namespace deif<pid>h<i> with eth0 = 10.211.<domain>.<i>/24, joined by a
bridge in deif<pid>br. Packet loss is a random drop of a host's outgoing packets on eth0
(iptables -m statistic: the kernel here has no netem); a partition takes a host's link down
at the bridge. Needs root. Everything is removed on every exit path (remove(), also called
at interpreter exit); namespaces left by a launcher that was killed with -9 are removed by
the next launcher (their pid no longer exists).
"""
import atexit
import os
import re
import subprocess

_NAME = re.compile(r"^deif(\d+)(h\d+|br)$")


class HostsError(Exception):
    pass


def _ip(*args, check=True):
    proc = subprocess.run(["ip", *args], capture_output=True, text=True)
    if check and proc.returncode != 0:
        raise HostsError(f"ip {' '.join(args)}: {proc.stderr.strip()}")
    return proc


def require_root(what="--hosts"):
    if os.geteuid() != 0:
        raise HostsError(f"{what} needs root (it creates network namespaces); run as root or without it")


def remove_leftovers():
    """Removes namespaces of launchers that no longer run. Returns their names."""
    proc = _ip("netns", "list", check=False)
    removed = []
    for line in proc.stdout.splitlines():
        name = line.split()[0] if line.split() else ""
        m = _NAME.match(name)
        if m and not os.path.exists(f"/proc/{m.group(1)}"):
            _ip("netns", "delete", name, check=False)
            removed.append(name)
    return removed


class Hosts:
    def __init__(self, count, domain):
        if count < 1:
            raise HostsError("--hosts must be >= 1")
        self.count = count
        self.domain = domain
        self.tag = f"deif{os.getpid()}"
        self.bridge = f"{self.tag}br"
        self.names = [f"{self.tag}h{i}" for i in range(1, count + 1)]
        self._created = []
        self._cut = set()

    def address(self, host):
        return f"10.211.{self.domain}.{host}"

    def namespace(self, host):
        return self.names[host - 1]

    def command(self, host, argv):
        """argv run inside host (1-based)."""
        return ["ip", "netns", "exec", self.namespace(host), *argv]

    def create(self):
        require_root()
        remove_leftovers()
        atexit.register(self.remove)
        try:
            _ip("netns", "add", self.bridge)
            self._created.append(self.bridge)
            _ip("-n", self.bridge, "link", "add", "br0", "type", "bridge")
            _ip("-n", self.bridge, "link", "set", "br0", "up")
            for i, name in enumerate(self.names, start=1):
                _ip("netns", "add", name)
                self._created.append(name)
                _ip("link", "add", "eth0", "netns", name, "type", "veth", "peer", "name", f"v{i}",
                    "netns", self.bridge)
                _ip("-n", self.bridge, "link", "set", f"v{i}", "master", "br0")
                _ip("-n", self.bridge, "link", "set", f"v{i}", "up")
                _ip("-n", name, "addr", "add", f"{self.address(i)}/24", "dev", "eth0")
                _ip("-n", name, "link", "set", "eth0", "up")
                _ip("-n", name, "link", "set", "lo", "up")
                # Multicast (SPDP discovery) leaves by eth0, across the bridge.
                _ip("-n", name, "route", "add", "224.0.0.0/4", "dev", "eth0")
        except BaseException:
            self.remove()
            raise
        return self

    def set_loss(self, host, probability):
        """Drops each outgoing packet of host on eth0 with this probability (0 removes it)."""
        ns = self.namespace(host)
        subprocess.run(["ip", "netns", "exec", ns, "iptables", "-F", "OUTPUT"], capture_output=True)
        if probability > 0:
            proc = subprocess.run(
                ["ip", "netns", "exec", ns, "iptables", "-A", "OUTPUT", "-o", "eth0", "-m",
                 "statistic", "--mode", "random", "--probability", f"{probability:.6f}", "-j",
                 "DROP"], capture_output=True, text=True)
            if proc.returncode != 0:
                raise HostsError(f"iptables in {ns}: {proc.stderr.strip()} (is iptables installed?)")

    def cut(self, host):
        """Cuts host off from every other host (its link at the bridge goes down)."""
        _ip("-n", self.bridge, "link", "set", f"v{host}", "down")
        self._cut.add(host)

    def heal(self, host):
        _ip("-n", self.bridge, "link", "set", f"v{host}", "up")
        self._cut.discard(host)

    def remove(self):
        """Removes every namespace (and with them the links and rules). Idempotent."""
        for name in reversed(self._created):
            _ip("netns", "delete", name, check=False)
        self._created = []

    def __enter__(self):
        return self.create()

    def __exit__(self, *exc):
        self.remove()
        return False
