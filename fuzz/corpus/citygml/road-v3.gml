<?xml version="1.0" encoding="UTF-8"?>
<core:CityModel xmlns:core="http://www.opengis.net/citygml/3.0" xmlns:tran="http://www.opengis.net/citygml/transportation/3.0" xmlns:dem="http://www.opengis.net/citygml/relief/3.0" xmlns:gen="http://www.opengis.net/citygml/generics/3.0" xmlns:gml="http://www.opengis.net/gml/3.2">
<core:cityObjectMember><tran:Road gml:id="r"><core:genericAttribute><gen:DoubleAttribute><gen:name>width</gen:name><gen:value>7.5</gen:value></gen:DoubleAttribute></core:genericAttribute>
<tran:section><tran:Section><tran:trafficSpace><tran:TrafficSpace><core:boundary><tran:TrafficArea gml:id="ta"><core:lod2MultiSurface><gml:MultiSurface><gml:surfaceMember>
<gml:Surface srsName="EPSG:32755"><gml:patches><gml:PolygonPatch><gml:exterior><gml:LinearRing><gml:posList>320971 5813650 0 321000 5813650 0 321000 5813700 0 320971 5813650 0</gml:posList></gml:LinearRing></gml:exterior></gml:PolygonPatch></gml:patches></gml:Surface>
</gml:surfaceMember></gml:MultiSurface></core:lod2MultiSurface></tran:TrafficArea></core:boundary></tran:TrafficSpace></tran:trafficSpace></tran:Section></tran:section></tran:Road></core:cityObjectMember>
<core:cityObjectMember><dem:ReliefFeature gml:id="rf"><dem:lod>2</dem:lod><dem:reliefComponent><dem:TINRelief gml:id="tin"><dem:lod>2</dem:lod><dem:tin><gml:TriangulatedSurface><gml:patches>
<gml:Triangle><gml:exterior><gml:LinearRing><gml:posList>320971 5813650 1 321000 5813650 2 321000 5813700 3 320971 5813650 1</gml:posList></gml:LinearRing></gml:exterior></gml:Triangle>
</gml:patches></gml:TriangulatedSurface></dem:tin></dem:TINRelief></dem:reliefComponent></dem:ReliefFeature></core:cityObjectMember>
</core:CityModel>
