"""IFC classes bimtiles leaves out (openings, spaces, annotations, grids...), shared by the IFC
cross-checks: an independent reader keeps only the products bimtiles keeps."""

EXCLUDED = (
    "IfcOpeningElement",
    "IfcVoidingFeature",
    "IfcSpace",
    "IfcSpatialZone",
    "IfcExternalSpatialElement",
    "IfcAnnotation",
    "IfcGrid",
    "IfcVirtualElement",
)
