"""Answers the proxy has never seen: prefixes, SIRI 1.x and 2.x, missing optional elements, several deliveries,
bare Siri documents, very large answers; and what it must refuse, with a clear error."""

from __future__ import annotations

import pytest

from proxies.replay_core import Visit
from proxies.siri_xml import ServiceClock, SiriError, SoapFault, build_fault, build_response, parse_response

CLOCK = ServiceClock.for_date("20220222")
T0 = CLOCK.epoch(8 * 3600)


def _visit(i: int = 0, **kw) -> Visit:
    base = dict(stop_id=f"S{i}", vehicle=f"V{i}", line="1001", direction="1", journey=f"J{i}", trip_id=f"J{i}",
                order=i + 1, aimed_arrival=8 * 3600 + 60.0, expected_arrival=8 * 3600 + 120.0,
                expected_departure=8 * 3600 + 150.0, at_stop=False, monitored=True)
    base.update(kw)
    return Visit(**base)


def test_round_trip_of_our_own_answer():
    d = parse_response(build_response([_visit(0, lon=24.9, lat=60.17), _visit(1, at_stop=True)], 8 * 3600, CLOCK))
    assert d.response_time == T0 and d.version == "2.0" and d.deliveries == 1
    a, b = d.calls
    assert (a.stop_id, a.vehicle, a.line, a.direction, a.journey, a.order) == ("S0", "V0", "1001", "1", "J0", 1)
    assert a.expected_arrival == T0 + 120.0 and a.expected_departure == T0 + 150.0 and a.aimed_arrival == T0 + 60.0
    assert (a.lon, a.lat) == (pytest.approx(24.9), pytest.approx(60.17)) and b.lon is None and b.at_stop


SIRI1 = b"""<?xml version="1.0"?>
<S:Envelope xmlns:S="http://schemas.xmlsoap.org/soap/envelope/"><S:Body>
<ns2:GetStopMonitoringResponse xmlns:ns2="http://wsdl.siri.org.uk" xmlns:ns3="http://www.siri.org.uk/siri">
<ServiceDeliveryInfo><ns3:ResponseTimestamp>2022-02-22T06:00:00Z</ns3:ResponseTimestamp></ServiceDeliveryInfo>
<Answer>
 <ns3:StopMonitoringDelivery version="1.3"><ns3:ResponseTimestamp>2022-02-22T06:00:00Z</ns3:ResponseTimestamp>
  <ns3:MonitoredStopVisit><ns3:MonitoringRef>A</ns3:MonitoringRef>
   <ns3:MonitoredVehicleJourney><ns3:LineRef>7</ns3:LineRef>
    <ns3:VehicleRef>bus-1</ns3:VehicleRef>
    <ns3:MonitoredCall><ns3:StopPointRef>A</ns3:StopPointRef><ns3:VisitNumber>4</ns3:VisitNumber>
     <ns3:ExpectedArrivalTime>2022-02-22T08:02:00+02:00</ns3:ExpectedArrivalTime></ns3:MonitoredCall>
   </ns3:MonitoredVehicleJourney></ns3:MonitoredStopVisit>
 </ns3:StopMonitoringDelivery>
 <ns3:StopMonitoringDelivery version="1.3"><ns3:ResponseTimestamp>2022-02-22T06:00:00Z</ns3:ResponseTimestamp>
  <ns3:MonitoredStopVisit><ns3:MonitoredVehicleJourney><ns3:VehicleRef>bus-2</ns3:VehicleRef>
   <ns3:FramedVehicleJourneyRef><ns3:DataFrameRef>2022-02-22</ns3:DataFrameRef>
    <ns3:DatedVehicleJourneyRef>J2</ns3:DatedVehicleJourneyRef></ns3:FramedVehicleJourneyRef>
   <ns3:Monitored>false</ns3:Monitored>
   <ns3:MonitoredCall><ns3:StopPointRef>B</ns3:StopPointRef></ns3:MonitoredCall>
  </ns3:MonitoredVehicleJourney></ns3:MonitoredStopVisit>
 </ns3:StopMonitoringDelivery>
</Answer><AnswerExtension/></ns2:GetStopMonitoringResponse></S:Body></S:Envelope>"""


def test_siri_1x_other_prefixes_several_deliveries_and_missing_optional_elements():
    d = parse_response(SIRI1)
    assert d.version == "1.3" and d.deliveries == 2 and len(d.calls) == 2
    a, b = d.calls
    assert a.order == 4 and a.expected_arrival == T0 + 120.0 and a.direction == "" and a.journey == ""
    assert a.expected_departure is None and a.aimed_arrival is None and a.monitored
    assert b.journey == "J2" and not b.monitored and b.expected_arrival is None and b.stop_id == "B"


def test_bare_siri_document_with_a_default_namespace_and_no_soap():
    doc = b"""<Siri xmlns="http://www.siri.org.uk/siri" version="2.1"><ServiceDelivery>
      <ResponseTimestamp>2022-02-22T08:00:00+02:00</ResponseTimestamp>
      <StopMonitoringDelivery version="2.1"><ResponseTimestamp>2022-02-22T08:00:00+02:00</ResponseTimestamp>
      <MonitoredStopVisit><MonitoringRef>X</MonitoringRef><MonitoredVehicleJourney>
        <VehicleRef>t9</VehicleRef><MonitoredCall><Order>2</Order>
        <ExpectedArrivalTime>2022-02-22T06:01:00Z</ExpectedArrivalTime></MonitoredCall>
      </MonitoredVehicleJourney></MonitoredStopVisit></StopMonitoringDelivery></ServiceDelivery></Siri>"""
    d = parse_response(doc)
    assert d.response_time == T0 and d.calls[0].stop_id == "X" and d.calls[0].expected_arrival == T0 + 60.0


def test_a_very_large_answer_is_read_and_an_oversized_one_refused(monkeypatch):
    visits = [_visit(i) for i in range(12_000)]
    data = build_response(visits, 8 * 3600, CLOCK)
    assert len(data) > 8_000_000
    assert len(parse_response(data).calls) == 12_000
    import proxies.siri_xml as sx

    monkeypatch.setattr(sx, "MAX_RESPONSE_BYTES", 1_000_000)
    with pytest.raises(SiriError, match="larger than"):
        parse_response(data)


@pytest.mark.parametrize("data, match", [
    (b"", "empty"),
    (b"\x00\xffgarbage<<", "malformed XML"),
    (build_response([_visit(0)], 8 * 3600, CLOCK)[:400], "malformed XML"),  # truncated
    (b"<html><body>Bad gateway</body></html>", "no StopMonitoringDelivery"),
    (b'<Siri xmlns="http://www.siri.org.uk/siri"><StopMonitoringDelivery/></Siri>', "ResponseTimestamp"),
    (b'<Siri xmlns="http://www.siri.org.uk/siri"><StopMonitoringDelivery><ResponseTimestamp>2022-02-22T08:00:00Z'
     b"</ResponseTimestamp><Status>false</Status><ErrorCondition><OtherError><ErrorText>no such stop</ErrorText>"
     b"</OtherError></ErrorCondition></StopMonitoringDelivery></Siri>", "no such stop"),
    (b'<Siri xmlns="http://www.siri.org.uk/siri"><StopMonitoringDelivery><ResponseTimestamp>yesterday'
     b"</ResponseTimestamp></StopMonitoringDelivery></Siri>", "bad dateTime"),
    (b'<!DOCTYPE x [<!ENTITY e SYSTEM "file:///etc/passwd">]><x>&e;</x>', "no StopMonitoringDelivery"),
])
def test_unusable_answers_are_refused_with_a_clear_error(data, match):
    with pytest.raises(SiriError, match=match):
        parse_response(data)


def test_soap_11_and_12_faults():
    with pytest.raises(SoapFault, match="backend down") as ei:
        parse_response(build_fault("soapenv:Server", "backend down"))
    assert ei.value.code == "soapenv:Server"
    f12 = (b'<e:Envelope xmlns:e="http://www.w3.org/2003/05/soap-envelope"><e:Body><e:Fault><e:Code><e:Value>'
           b"e:Receiver</e:Value></e:Code><e:Reason><e:Text>later</e:Text></e:Reason></e:Fault></e:Body></e:Envelope>")
    with pytest.raises(SoapFault, match="later"):
        parse_response(f12)


def test_an_empty_delivery_is_an_answer_with_no_calls():
    d = parse_response(build_response([], 8 * 3600, CLOCK))
    assert d.calls == [] and d.deliveries == 1
