"""Where a live run's sweeps come from: ``velodyne://HOST:PORT``, ``ouster://HOST:PORT`` or a
recording paced at its recorded rate (``--realtime``)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

DEFAULT_PORTS = {"velodyne": 2368, "ouster": 7502}


@dataclass(frozen=True)
class Source:
    """A parsed live source.

    Attributes
    ----------
    kind : ``velodyne``, ``ouster`` or ``file``
    host, port : the address to listen on (sensors)
    path : the recording (``file``)
    """

    kind: str
    host: str = ""
    port: int = 0
    path: Path | None = None

    def __str__(self) -> str:
        return str(self.path) if self.kind == "file" else f"{self.kind}://{self.host}:{self.port}"


def parse_address(text: str, default_port: int, what: str) -> tuple[str, int]:
    """``HOST[:PORT]`` → (host, port); ValueError naming ``what`` when malformed."""
    host, sep, port = text.rpartition(":")
    if not sep:
        host, port = text, str(default_port)
    host = host.strip("[]") or "0.0.0.0"
    try:
        number = int(port)
    except ValueError:
        raise ValueError(f"{what}: port {port!r} is not a number") from None
    if not 0 <= number <= 65535:
        raise ValueError(f"{what}: port {number} out of range 0..65535")
    return host, number


def parse_source(text: str) -> Source:
    """Parse a live source: ``velodyne://HOST[:PORT]`` (default port 2368), ``ouster://HOST[:PORT]``
    (7502) or the path of a recording."""
    scheme, sep, rest = text.partition("://")
    if not sep:
        path = Path(text)
        if not path.exists():
            raise ValueError(
                f"SOURCE {text}: no such file; give velodyne://HOST:PORT, ouster://HOST:PORT or a recording"
            )
        return Source("file", path=path)
    scheme = scheme.lower()
    if scheme not in DEFAULT_PORTS:
        raise ValueError(f"SOURCE {text}: unknown scheme {scheme!r}; use velodyne:// or ouster://")
    host, port = parse_address(rest.rstrip("/"), DEFAULT_PORTS[scheme], f"SOURCE {text}")
    return Source(scheme, host, port)
