"""SIRI StopMonitoring on the wire: the producer's SOAP answers, and a tolerant, fast reader of any producer's.

Writing: the RPC/literal shape of the CEN `siri_wsProducer.wsdl` (`GetStopMonitoringResponse` with unqualified
`ServiceDeliveryInfo`, `Answer`, `AnswerExtension`; the SIRI content qualified), in the XSD's element order, so
that the answers validate against the CEN schema (tests do so when ../shared is there).

Reading (`parse_response`): zeep builds and sends the request from the operator's WSDL, but its answer is read
here with lxml by local names, because answers in the field differ in ways a strict binding refuses: namespace
prefixes (or none), SIRI 1.x and 2.x, optional elements missing, several StopMonitoringDelivery elements (one per
stop), `Siri/ServiceDelivery` documents posted without SOAP. This reader also costs a fraction of zeep's object
binding on answers of thousands of visits. What cannot be read raises `SiriError` with a clear message.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from datetime import UTC, datetime, timedelta, timezone
from typing import NamedTuple
from xml.sax.saxutils import escape

from lxml import etree

from proxies.replay_core import Visit

SOAP_ENV = "http://schemas.xmlsoap.org/soap/envelope/"
SOAP12_ENV = "http://www.w3.org/2003/05/soap-envelope"
SIRI_NS = "http://www.siri.org.uk/siri"
SIRI_WS = "http://wsdl.siri.org.uk"
MAX_RESPONSE_BYTES = 64 << 20  # an answer larger than this is refused, not parsed
PARSER = etree.XMLParser(resolve_entities=False, no_network=True, huge_tree=True, remove_comments=True)


class SiriError(ValueError):
    """An answer that cannot be used (not XML, a SOAP fault, no StopMonitoringDelivery, a bad value)."""


class SoapFault(SiriError):
    """The service answered with a SOAP fault; the fault code and text are kept for the log."""

    def __init__(self, code: str, text: str):
        super().__init__(f"SOAP fault {code}: {text}")
        self.code, self.text = code, text


@dataclass(frozen=True)
class ServiceClock:
    """Service-day seconds <-> wall time: `midnight` is the service day's 00:00 (GTFS times count from noon
    minus 12 h, the same except on the days the clocks change)."""

    midnight: datetime

    @classmethod
    def for_date(cls, yyyymmdd: str, utc_offset_h: float = 2.0) -> ServiceClock:
        """The clock of a GTFS service date (YYYYMMDD) at a fixed UTC offset (Helsinki winter time
        by default, the bundled feed's)."""
        tz = timezone(timedelta(hours=utc_offset_h))
        d = datetime.strptime(yyyymmdd or "20220222", "%Y%m%d").replace(tzinfo=tz)
        return cls(d)

    def iso(self, s: float) -> str:
        """Wall time of a service-day second, as the ISO 8601 SIRI writes."""
        return (self.midnight + timedelta(seconds=round(s, 3))).isoformat()

    def epoch(self, s: float) -> float:
        """POSIX seconds of a service-day second."""
        return self.midnight.timestamp() + s


def _e(tag: str, text) -> str:
    return f"<siri:{tag}>{escape(str(text))}</siri:{tag}>"


def _visit_xml(v: Visit, clock: ServiceClock, now_iso: str, date: str) -> str:
    parts = [
        "<siri:MonitoredStopVisit>",
        _e("RecordedAtTime", now_iso),
        _e("MonitoringRef", v.stop_id),
        "<siri:MonitoredVehicleJourney>",
        _e("LineRef", v.line),
        _e("DirectionRef", v.direction),
        "<siri:FramedVehicleJourneyRef>", _e("DataFrameRef", date), _e("DatedVehicleJourneyRef", v.journey),
        "</siri:FramedVehicleJourneyRef>",
        _e("VehicleMode", v.mode),
        _e("Monitored", "true" if v.monitored else "false"),
    ]
    if v.lon is not None and v.lat is not None:
        parts += ["<siri:VehicleLocation>", _e("Longitude", f"{v.lon:.7f}"), _e("Latitude", f"{v.lat:.7f}"),
                  "</siri:VehicleLocation>"]
    if v.vehicle:
        parts.append(_e("VehicleRef", v.vehicle))
    parts += [
        "<siri:MonitoredCall>",
        _e("StopPointRef", v.stop_id),
        _e("Order", v.order),
        _e("VehicleAtStop", "true" if v.at_stop else "false"),
        _e("AimedArrivalTime", clock.iso(v.aimed_arrival)),
        _e("ExpectedArrivalTime", clock.iso(v.expected_arrival)),
        _e("ExpectedDepartureTime", clock.iso(v.expected_departure)),
        "</siri:MonitoredCall>",
        "</siri:MonitoredVehicleJourney>",
        "</siri:MonitoredStopVisit>",
    ]
    return "".join(parts)


def build_response(visits: list[Visit], now: float, clock: ServiceClock, *, producer: str = "entitynet-replay",
                   operation: str = "GetStopMonitoring", version: str = "2.0") -> bytes:
    """The SOAP 1.1 answer to GetStopMonitoring / GetMultipleStopMonitoring: one StopMonitoringDelivery."""
    now_iso = clock.iso(now)
    date = clock.midnight.date().isoformat()
    body = "".join(_visit_xml(v, clock, now_iso, date) for v in visits)
    xml = (
        f'<?xml version="1.0" encoding="UTF-8"?>'
        f'<soapenv:Envelope xmlns:soapenv="{SOAP_ENV}"><soapenv:Body>'
        f'<siriWS:{operation}Response xmlns:siriWS="{SIRI_WS}" xmlns:siri="{SIRI_NS}">'
        f"<ServiceDeliveryInfo>{_e('ResponseTimestamp', now_iso)}{_e('ProducerRef', producer)}</ServiceDeliveryInfo>"
        f'<Answer><siri:StopMonitoringDelivery version="{version}">{_e("ResponseTimestamp", now_iso)}'
        f"{_e('Status', 'true')}{body}</siri:StopMonitoringDelivery></Answer>"
        f"<AnswerExtension/></siriWS:{operation}Response></soapenv:Body></soapenv:Envelope>"
    )
    return xml.encode()


def build_fault(code: str = "soapenv:Server", text: str = "service unavailable") -> bytes:
    """A SOAP 1.1 fault envelope: what the replay answers when it injects a fault."""
    return (
        f'<?xml version="1.0" encoding="UTF-8"?><soapenv:Envelope xmlns:soapenv="{SOAP_ENV}"><soapenv:Body>'
        f"<soapenv:Fault><faultcode>{escape(code)}</faultcode><faultstring>{escape(text)}</faultstring>"
        f"</soapenv:Fault></soapenv:Body></soapenv:Envelope>"
    ).encode()


# ---------------------------------------------------------------------------------------------- reading
class Call(NamedTuple):
    """One MonitoredStopVisit as read from any producer. Times are POSIX seconds (None when absent). A named
    tuple rather than a frozen dataclass: an answer makes thousands and the tuple is built in C, several
    times faster."""

    stop_id: str
    vehicle: str
    line: str
    direction: str
    journey: str
    order: int | None
    expected_arrival: float | None
    expected_departure: float | None
    aimed_arrival: float | None
    at_stop: bool
    monitored: bool
    lon: float | None
    lat: float | None


@dataclass
class Delivery:
    """One parsed StopMonitoring answer: the calls and the producer's ResponseTimestamp, which the fleet
    uses to estimate the producer's clock offset."""
    response_time: float  # the producer's ResponseTimestamp (POSIX seconds)
    calls: list[Call]
    version: str
    deliveries: int  # how many StopMonitoringDelivery elements


def _local(el) -> str:
    tag = el.tag
    if not isinstance(tag, str):
        return ""
    return tag.rsplit("}", 1)[-1]


def _t(el, path: str) -> str | None:
    """The stripped text at a `{*}`-wildcard path (any namespace or none), or None."""
    v = el.findtext(path)
    if v is None:
        return None
    v = v.strip()
    return v or None


def parse_time(text: str | None, _cache: dict[str, float] = {}) -> float | None:  # noqa: B006 - a memo
    """An xsd:dateTime to POSIX seconds; a time without an offset is taken as UTC. (Answers repeat the same
    few hundred minute stamps thousands of times: memoised.)"""
    if not text:
        return None
    got = _cache.get(text)
    if got is not None:
        return got
    try:
        d = datetime.fromisoformat(text.replace("Z", "+00:00"))
    except ValueError:
        raise SiriError(f"bad dateTime {text!r}") from None
    if d.tzinfo is None:
        d = d.replace(tzinfo=UTC)
    if len(_cache) > 100_000:
        _cache.clear()
    _cache[text] = got = d.timestamp()
    return got


def _float(text: str | None) -> float | None:
    if text is None:
        return None
    try:
        v = float(text)
    except ValueError:
        return None
    return v if math.isfinite(v) else None


def _true(text: str | None, default: bool) -> bool:
    if text is None:
        return default
    return text.lower() in ("true", "1")


#: the elements of a MonitoredStopVisit the proxy reads (any namespace)
_FIELDS = frozenset(("MonitoredVehicleJourney", "StopPointRef", "MonitoringRef", "DatedVehicleJourneyRef",
                     "VehicleJourneyRef", "Longitude", "Latitude", "Order", "VisitNumber", "VehicleRef", "LineRef",
                     "DirectionRef", "ExpectedArrivalTime", "ExpectedDepartureTime", "AimedArrivalTime",
                     "VehicleAtStop", "Monitored"))
#: full tag (with its namespace, whatever it is) -> the field's local name, or None for every other element; an
#: answer has a few dozen distinct tags, so this stays small (bounded all the same)
_TAG_NAMES: dict[object, str | None] = {}


def _field_of(tag) -> str | None:
    name = None
    if isinstance(tag, str):
        local = tag[tag.rfind("}") + 1:]
        if local in _FIELDS:
            name = local
    if len(_TAG_NAMES) > 10_000:
        _TAG_NAMES.clear()
    _TAG_NAMES[tag] = name
    return name


def _flat(visit) -> dict[str, str]:
    """Local name -> stripped text of the elements the proxy reads, the first occurrence of each (a visit's
    fields of interest have unique names, wherever a producer nests them). One walk over the visit's elements
    with the tag looked up in `_TAG_NAMES`: about twice as fast as lxml's wildcard tag filter (`{*}name` for 17
    names) plus a split of every tag, and the proxy's largest cost per answer."""
    out: dict[str, str] = {}
    names = _TAG_NAMES
    for el in visit.iter():
        tag = el.tag
        name = names[tag] if tag in names else _field_of(tag)
        if name is not None and name not in out:
            text = el.text
            out[name] = text.strip() if text else ""
    return out


def _call(visit) -> Call | None:
    f = _flat(visit)
    if "MonitoredVehicleJourney" not in f:
        return None
    g = f.get
    stop = g("StopPointRef") or g("MonitoringRef") or ""
    journey = g("DatedVehicleJourneyRef") or g("VehicleJourneyRef") or ""
    lon, lat = _float(g("Longitude")), _float(g("Latitude"))
    if lon is None or lat is None or not (-180.0 <= lon <= 180.0 and -90.0 <= lat <= 90.0):
        lon = lat = None
    o = g("Order") or g("VisitNumber")
    return Call(
        stop_id=stop,
        vehicle=g("VehicleRef") or "",
        line=g("LineRef") or "",
        direction=g("DirectionRef") or "",
        journey=journey,
        order=int(o) if o and o.isdigit() else None,
        expected_arrival=parse_time(g("ExpectedArrivalTime")),
        expected_departure=parse_time(g("ExpectedDepartureTime")),
        aimed_arrival=parse_time(g("AimedArrivalTime")),
        at_stop=_true(g("VehicleAtStop") or None, False),
        monitored=_true(g("Monitored") or None, True),
        lon=lon,
        lat=lat,
    )


def parse_response(data: bytes) -> Delivery:
    """Every MonitoredStopVisit of a GetStopMonitoring answer (SOAP 1.1/1.2 or a bare Siri document)."""
    if len(data) > MAX_RESPONSE_BYTES:
        raise SiriError(f"answer of {len(data)} bytes is larger than the {MAX_RESPONSE_BYTES} allowed")
    if not data.strip():
        raise SiriError("empty answer")
    try:
        root = etree.fromstring(data, PARSER)
    except etree.XMLSyntaxError as exc:
        raise SiriError(f"malformed XML: {exc}") from None
    for tag in (f"{{{SOAP_ENV}}}Fault", f"{{{SOAP12_ENV}}}Fault"):
        for el in root.iter(tag):
            code = _t(el, "faultcode") or _t(el, "{*}Code/{*}Value") or "?"
            text = _t(el, "faultstring") or _t(el, "{*}Reason/{*}Text") or ""
            raise SoapFault(code, text)
    deliveries = list(root.iter("{*}StopMonitoringDelivery"))
    if not deliveries:
        raise SiriError(f"no StopMonitoringDelivery in the answer (root element {_local(root)!r})")
    stamp = None
    for el in root.iter("{*}ResponseTimestamp"):
        stamp = parse_time(el.text.strip() if el.text else None)
        break
    if stamp is None:
        raise SiriError("the answer has no ResponseTimestamp")
    version = deliveries[0].get("version", "")
    calls: list[Call] = []
    for d in deliveries:
        status = _t(d, "{*}Status")
        if status is not None and status.lower() == "false":
            err = d.find("{*}ErrorCondition")
            why = " ".join(t.strip() for t in err.itertext() if t.strip()) if err is not None else ""
            raise SiriError(f"StopMonitoringDelivery with Status false: {why or 'no reason given'}")
        for v in d.iterchildren("{*}MonitoredStopVisit"):
            c = _call(v)
            if c is not None:
                calls.append(c)
    return Delivery(stamp, calls, version, len(deliveries))


def parse_request_stops(data: bytes) -> tuple[str, list[str]]:
    """(operation, stop ids) of a GetStopMonitoring / GetMultipleStopMonitoring request (the producer side)."""
    try:
        root = etree.fromstring(data, PARSER)
    except etree.XMLSyntaxError as exc:
        raise SiriError(f"malformed XML: {exc}") from None
    body = root.find("{*}Body")
    if body is None or len(body) == 0:
        raise SiriError("no SOAP Body")
    op = _local(body[0])
    stops = [el.text.strip() for el in body[0].iter("{*}MonitoringRef") if el.text and el.text.strip()]
    return op, stops
