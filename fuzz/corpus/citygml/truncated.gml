<?xml version="1.0" encoding="UTF-8"?>
<core:CityModel xmlns:core="http://www.opengis.net/citygml/2.0" xmlns:bldg="http://www.opengis.net/citygml/building/2.0" xmlns:gen="http://www.opengis.net/citygml/generics/2.0" xmlns:app="http://www.opengis.net/citygml/appearance/2.0" xmlns:gml="http://www.opengis.net/gml" xmlns:xlink="http://www.w3.org/1999/xlink" xmlns:uro="https://www.geospatial.jp/iur/uro/2.0">
<gml:boundedBy><gml:Envelope srsName="urn:ogc:def:crs,crs:EPSG::25832,crs:EPSG::5783" srsDimension="3"><gml:lowerCorner>458870 5438350 110</gml:lowerCorner><gml:upperCorner>458880 5438360 120</gml:upperCorner></gml:Envelope></gml:boundedBy>
<core:cityObjectMember><bldg:Building gml:id="b1">
<gml:name>Seed &amp; house</gml:name>
<gen:stringAttribute name="note"><gen:value>seed</gen:value></gen:stringAttribute>
<gen:intAttribute name="floors"><gen:value>2</gen:value></gen:intAttribute>
<bldg:measuredHeight uom="m">10</bldg:measuredHeight>
<uro:buildingDetails><uro:BuildingDetails><uro:buildingID>X-1</uro:buildingID></uro:BuildingDetails></uro:buildingDetails>
<bldg:lod2Solid><gml:Solid><gml:exterior><gml:CompositeSurface gml:id="cs1">
<gml:surfaceMember xlink:href="#p1"/><gml:surfaceMember xlink:href="#p2"/>
<gml:surfaceMember><gml:OrientableSurface orientation="-"><gml:baseSurface xlink:href="#p1"/></gml:OrientableSurface></gml:surfaceMember>
</gml:CompositeSurface></gml:exterior></gml:Solid></bldg:lod2Solid>
<bldg:boundedBy><bldg:WallSurface gml:id="w1"><bldg:lod2MultiSurface>