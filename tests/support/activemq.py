"""A private ActiveMQ broker for one test module: its own configuration and data under a temporary folder, one
STOMP connector on 127.0.0.1 at a free port, nothing else (no OpenWire, web console, JMX or persistence).

Debian's `activemq` package (5.17; `.ci/setup` installs it) ships the broker as `/usr/share/activemq/bin/activemq.jar`
and an init-style `/usr/bin/activemq` that wants an instance under /etc/activemq and /var/lib/activemq. A test wants
none of that, so the JVM is started straight on the jar with `start xbean:file:<our activemq.xml>` (the jar's task
`start` runs the broker in the foreground; the script's `console` is the same task) and killed with its process group:

    java -Dactivemq.home=/usr/share/activemq -Dactivemq.base=TMP -Dactivemq.conf=TMP -Dactivemq.data=TMP/data \\
         -jar /usr/share/activemq/bin/activemq.jar start xbean:file:TMP/activemq.xml

It is ready when its STOMP connector answers a CONNECT frame with CONNECTED (polled, with a deadline): the port
accepting connections is not enough, the transport connector opens before the broker has finished starting.
"""

from __future__ import annotations

import os
import shutil
import signal
import socket
import subprocess
import tempfile
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

ACTIVEMQ_HOME = Path("/usr/share/activemq")
ACTIVEMQ_JAR = ACTIVEMQ_HOME / "bin" / "activemq.jar"

# persistent="false": no KahaDB store; useJmx="false" and createConnector="false": no JMX port; advisorySupport off:
# no advisory topics a test never reads; useShutdownHook="false": a SIGTERM ends the JVM at once (the test owns it);
# a memory limit within the small heap below (the default 1 GB draws a warning on every start).
BROKER_XML = """<beans xmlns="http://www.springframework.org/schema/beans"
  xmlns:xsi="http://www.w3.org/2001/XMLSchema-instance"
  xsi:schemaLocation="http://www.springframework.org/schema/beans
    http://www.springframework.org/schema/beans/spring-beans.xsd
    http://activemq.apache.org/schema/core http://activemq.apache.org/schema/core/activemq-core.xsd">
  <broker xmlns="http://activemq.apache.org/schema/core" brokerName="eca-test" useJmx="false" persistent="false"
          advisorySupport="false" schedulerSupport="false" useShutdownHook="false" dataDirectory="{data}">
    <managementContext><managementContext createConnector="false"/></managementContext>
    <systemUsage><systemUsage><memoryUsage><memoryUsage limit="64 mb"/></memoryUsage></systemUsage></systemUsage>
    <transportConnectors>
      <transportConnector name="stomp" uri="stomp://127.0.0.1:{port}"/>
    </transportConnectors>
  </broker>
</beans>
"""

# The Debian build logs through log4j 1.2 (slf4j-log4j12); without a configuration it warns and says nothing.
LOG4J = """log4j.rootLogger=WARN, out
log4j.appender.out=org.apache.log4j.ConsoleAppender
log4j.appender.out.layout=org.apache.log4j.PatternLayout
log4j.appender.out.layout.ConversionPattern=%-5p %c{1} %m%n
"""


def activemq_missing() -> str | None:
    """Why no private broker can run here (for pytest's skip), or None."""
    if shutil.which("java") is None:
        return "no java on PATH (install Debian's activemq package: apt-get install activemq)"
    if not ACTIVEMQ_JAR.is_file():
        return f"no {ACTIVEMQ_JAR} (install Debian's activemq package: apt-get install activemq)"
    return None


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def stomp_answers(port: int, timeout_s: float = 1.0) -> bool:
    """Whether a STOMP broker on 127.0.0.1:`port` answers CONNECT with CONNECTED now."""
    try:
        with socket.create_connection(("127.0.0.1", port), timeout=timeout_s) as s:
            s.sendall(b"CONNECT\naccept-version:1.2\nhost:localhost\n\n\x00")
            got = b""
            while b"\x00" not in got:
                chunk = s.recv(4096)
                if not chunk:
                    return False
                got += chunk
            s.sendall(b"DISCONNECT\n\n\x00")
            return got.lstrip(b"\r\n").startswith(b"CONNECTED")
    except OSError:
        return False


class ActiveMQ:
    """One broker process; `port` stays the same across `restart` (a client reconnects to the same address)."""

    def __init__(self, directory: Path, port: int | None = None) -> None:
        self.directory = directory
        self.port = port or free_port()
        self.proc: subprocess.Popen[bytes] | None = None
        self.startup_s = 0.0
        (directory / "activemq.xml").write_text(BROKER_XML.format(data=directory / "data", port=self.port))
        (directory / "log4j.properties").write_text(LOG4J)
        self.log_path = directory / "broker.log"

    def command(self) -> list[str]:
        d = self.directory
        return ["java", "-Xms32m", "-Xmx256m", "-XX:+UseSerialGC", "-XX:TieredStopAtLevel=1",
                "-Djava.awt.headless=true", f"-Dactivemq.home={ACTIVEMQ_HOME}", f"-Dactivemq.base={d}",
                f"-Dactivemq.conf={d}", f"-Dactivemq.data={d / 'data'}",
                f"-Dlog4j.configuration=file:{d}/log4j.properties",
                "-jar", str(ACTIVEMQ_JAR), "start", f"xbean:file:{d / 'activemq.xml'}"]

    def start(self, timeout_s: float = 60.0) -> None:
        t0 = time.monotonic()
        with open(self.log_path, "ab") as log:
            self.proc = subprocess.Popen(self.command(), stdout=log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                                         cwd=self.directory, start_new_session=True)
        deadline = t0 + timeout_s
        while not stomp_answers(self.port):
            if self.proc.poll() is not None:
                raise RuntimeError(f"ActiveMQ exited with {self.proc.returncode} before its STOMP port answered:\n"
                                   f"{self.log_tail()}")
            if time.monotonic() > deadline:
                self.stop()
                raise RuntimeError(f"ActiveMQ's STOMP port {self.port} did not answer within {timeout_s:g} s:\n"
                                   f"{self.log_tail()}")
            try:  # the pace of the poll: returns early if the JVM dies
                self.proc.wait(0.1)
            except subprocess.TimeoutExpired:
                pass
        self.startup_s = time.monotonic() - t0

    def stop(self) -> None:
        proc, self.proc = self.proc, None
        if proc is None or proc.poll() is not None:
            return
        os.killpg(proc.pid, signal.SIGTERM)
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait(timeout=10)

    def restart(self, timeout_s: float = 60.0) -> None:
        self.stop()
        self.start(timeout_s)

    def log_tail(self, lines: int = 30) -> str:
        try:
            return "\n".join(self.log_path.read_text(errors="replace").splitlines()[-lines:])
        except OSError:
            return "(no log)"


@contextmanager
def private_activemq(timeout_s: float = 60.0) -> Iterator[ActiveMQ]:
    """A running private broker (RuntimeError when it cannot start; check `activemq_missing` first), stopped and its
    folder removed at exit."""
    directory = Path(tempfile.mkdtemp(prefix="eca-amq-"))
    broker = ActiveMQ(directory)
    try:
        broker.start(timeout_s)
        yield broker
    finally:
        broker.stop()
        shutil.rmtree(directory, ignore_errors=True)
