"""The SIRI StopMonitoring consumer: zeep on the operator's WSDL, synchronous (the proxy's shell runs it in a
worker thread, off the trio loop).

zeep builds and sends the request from the WSDL (RPC/literal as in the CEN `siri_wsProducer.wsdl`, or our own
minimal `proxies/wsdl/siri-sm.wsdl`); the answer comes back raw and is read by `siri_xml.parse_response`. Two
facts about the CEN WSDLs under zeep 4.3 are handled here: `WsServiceRequestInfoStructure` comes out with the
`RequestTimestamp` element several times (zeep wants a value for every copy and emits them all, which the XSD
rejects: `DedupPlugin` drops the extra copies on the way out), and `RequestExtension` is required (an empty one
is passed). The service address in a WSDL is a placeholder: the operation is bound to `--url`.

Errors come out classified, so the shell can count them: `SoapFault`, `HttpError` (status), `Timeout`,
`Unreachable`, `SiriError` (not a usable answer).
"""

from __future__ import annotations

import itertools
import time
from dataclasses import dataclass, field
from datetime import UTC, datetime, timedelta
from importlib import resources
from pathlib import Path

import requests
import zeep
import zeep.exceptions
from lxml import etree
from zeep.plugins import Plugin
from zeep.transports import Transport

from proxies.siri_xml import SiriError, SoapFault, parse_response

SIRI = "http://www.siri.org.uk/siri"


class HttpError(SiriError):
    """The service answered with an HTTP error status (kept, so 4xx and 5xx are counted apart)."""

    def __init__(self, status: int, text: str = ""):
        super().__init__(f"HTTP {status}{': ' + text if text else ''}")
        self.status = status


class Timeout(SiriError):
    """No answer within the timeout: counted apart from refusals, since a slow service may recover."""


class Unreachable(SiriError):
    """No connection at all (DNS, refused, reset): the service or the network is down."""


@dataclass
class Fetched:
    """One poll's outcome: the raw answers of the requests that succeeded, the classified error of each that
    failed, and how many requests were not sent because the poll's time was used up. Why not raise
    at the first failure: with one request per stop (`--mode single`) a few failing stops stopped every poll
    before the others were asked, so no poll ever completed."""

    answers: list[bytes] = field(default_factory=list)
    failures: list[SiriError] = field(default_factory=list)
    not_sent: int = 0


def default_wsdl() -> str:
    """Our own minimal StopMonitoring WSDL shipped with the package (see proxies/wsdl/README.md)."""
    return str(resources.files("proxies") / "wsdl" / "siri-sm.wsdl")


class DedupPlugin(Plugin):
    """Drop repeated RequestTimestamp children of ServiceRequestInfo (a zeep artefact of the CEN WSDL)."""

    def egress(self, envelope, http_headers, operation, binding_options):
        """zeep's outgoing hook: remove the duplicate RequestTimestamp before the envelope is sent."""
        for info in envelope.iter("ServiceRequestInfo", "{*}ServiceRequestInfo"):
            seen = False
            for el in list(info):
                if isinstance(el.tag, str) and el.tag.endswith("RequestTimestamp"):
                    if seen:
                        info.remove(el)
                    seen = True
        return envelope, http_headers


class StopMonitoringClient:
    """GetMultipleStopMonitoring (all stops in one request, in chunks of `chunk`) or, where the service offers
    only that, one GetStopMonitoring per stop. `preview_s` (PreviewInterval) is 5 minutes: the motion uses the
    ETAs of the next stops and a vehicle enters the map 20 s before its first stop there, so visits further
    ahead are never used before the next poll (nor over a 2-minute outage); a 10-minute preview doubled what
    the proxy read and discarded for the same figures."""

    def __init__(self, url: str, wsdl: str | None = None, *, timeout: float = 10.0, requestor: str = "entitynet",
                 chunk: int = 500, preview_s: int = 300, mode: str = "auto") -> None:
        self.url = url
        self.wsdl = wsdl or default_wsdl()
        if not Path(self.wsdl).exists() and "://" not in self.wsdl:
            raise SiriError(f"WSDL {self.wsdl} not found")
        session = requests.Session()
        self.transport = Transport(session=session, timeout=timeout, operation_timeout=timeout)
        try:
            self.client = zeep.Client(self.wsdl, transport=self.transport, plugins=[DedupPlugin()])
        except (zeep.exceptions.Error, etree.XMLSyntaxError, OSError, requests.RequestException) as exc:
            raise SiriError(f"cannot load WSDL {self.wsdl}: {exc}") from None
        self.binding = self._find_binding()
        ops = self.client.wsdl.bindings[self.binding]._operations
        if mode == "auto":
            mode = "multiple" if "GetMultipleStopMonitoring" in ops else "single"
        if (mode == "multiple" and "GetMultipleStopMonitoring" not in ops) or "GetStopMonitoring" not in ops:
            raise SiriError(f"the WSDL's binding {self.binding} has no {mode} StopMonitoring operation")
        self.mode = mode
        self.service = self.client.create_service(self.binding, url)
        self.requestor = requestor
        self.chunk = max(1, int(chunk))
        self.preview = timedelta(seconds=int(preview_s))
        self._ids = itertools.count(1)
        info = self.client.get_type(self._info_type())
        self._stamp_fields = [name for name, _el in info.elements if name.startswith("RequestTimestamp")]

    def _find_binding(self) -> str:
        for name, binding in self.client.wsdl.bindings.items():
            if "GetStopMonitoring" in binding._operations and "Soap12" not in type(binding).__name__:
                return name
        raise SiriError(f"no SOAP binding with GetStopMonitoring in {self.wsdl}")

    def _info_type(self) -> str:
        op = self.client.wsdl.bindings[self.binding]._operations["GetStopMonitoring"]
        part = op.input.body.type.elements[0][1]
        return part.type.qname.text

    def _info(self, now: datetime) -> dict:
        d = {name: now for name in self._stamp_fields}
        d["RequestorRef"] = self.requestor
        d["MessageIdentifier"] = f"entitynet-{next(self._ids)}"
        return d

    def requests_for(self, stops: list[str]) -> int:
        """How many requests one poll of `stops` takes in the chosen mode (reported at start-up)."""
        return (len(stops) + self.chunk - 1) // self.chunk if self.mode == "multiple" else len(stops)

    def fetch(self, stops: list[str], deadline: float | None = None) -> Fetched:
        """The raw answers for `stops` (one per request) and the classified failures of the requests that failed;
        the other requests are sent all the same. No request is sent once `time.monotonic()` has passed
        `deadline` (default: two timeouts from now), so a poll ends by its deadline plus one timeout however many
        stops time out or answer slowly: the caller keeps the answers it got instead of losing the whole poll to
        its own time limit. Raises the first failure when no request succeeded: the poll failed as a whole."""
        now = datetime.now(UTC)
        if deadline is None:
            deadline = time.monotonic() + 2.0 * float(self.transport.operation_timeout or 0.0)
        if self.mode == "multiple":
            calls = [("GetMultipleStopMonitoring",
                      {"RequestTimestamp": now, "MessageIdentifier": f"entitynet-{next(self._ids)}",
                       "StopMonitoringFIlter": [{"MonitoringRef": s, "PreviewInterval": self.preview}
                                                for s in stops[i:i + self.chunk]], "version": "2.0"})
                     for i in range(0, len(stops), self.chunk)]
        else:
            calls = [("GetStopMonitoring", {"RequestTimestamp": now, "PreviewInterval": self.preview,
                                            "MonitoringRef": s, "version": "2.0"}) for s in stops]
        out = Fetched()
        for k, (op, req) in enumerate(calls):
            if k > 0 and time.monotonic() > deadline:
                out.not_sent = len(calls) - k
                break
            try:
                out.answers.append(self._call(op, now, req))
            except SiriError as exc:
                out.failures.append(exc)
        if out.failures and not out.answers:
            raise out.failures[0]
        return out

    def _call(self, op: str, now: datetime, req: dict) -> bytes:
        try:
            with self.client.settings(raw_response=True):
                resp = getattr(self.service, op)(ServiceRequestInfo=self._info(now), Request=req,
                                                 RequestExtension={})
        except requests.Timeout as exc:
            raise Timeout(f"no answer within {self.transport.operation_timeout} s: {exc}") from None
        except requests.ConnectionError as exc:
            raise Unreachable(f"cannot reach {self.url}: {exc}") from None
        except requests.RequestException as exc:
            raise Unreachable(f"request to {self.url} failed: {exc}") from None
        except (zeep.exceptions.Error, ValueError, TypeError) as exc:
            raise SiriError(f"cannot build the {op} request: {exc}") from None
        data = resp.content
        if resp.status_code >= 400:
            if b"Fault" in data[:4096] or b"Fault" in data[-4096:]:
                parse_response(data)  # raises the SoapFault with its code and text
            raise HttpError(resp.status_code, resp.reason or "")
        return data


__all__ = ["StopMonitoringClient", "Fetched", "DedupPlugin", "HttpError", "Timeout", "Unreachable", "SiriError",
           "SoapFault", "default_wsdl", "SIRI"]
