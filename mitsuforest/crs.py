"""The coordinate reference system of ``origin.crs``: checked by the scene file's validation, written
into LAS, LAZ and COPC headers. Imports no stage."""

from __future__ import annotations

from .errors import UserError


def crs_wkt(text: str) -> str:
    """The OGC WKT of the coordinate reference system ``text`` (``origin.crs``: ``"EPSG:7855"``, a
    PROJ string, WKT...), in WKT1 as GDAL and PDAL write it, which every LAS reader understands
    (WKT2 only for a system WKT1 cannot express).

    :raises UserError: ``origin.crs: ...`` when pyproj cannot make a coordinate system of ``text``, or
        when it is not projected in metres (see :func:`_metric_projection_problem`).
    """
    import pyproj  # here, so that scenes without a CRS do not pay for importing it
    try:
        crs = pyproj.CRS.from_user_input(text)
    except pyproj.exceptions.CRSError as e:
        raise UserError(f"origin.crs: {text!r} is not a coordinate reference system ({_proj_reason(e)}); "
                        "give an EPSG code such as 'EPSG:7855', a PROJ string or WKT") from None
    problem = _metric_projection_problem(crs)
    if problem:
        raise UserError(f"origin.crs: {text!r} ({crs.name}) {problem}; the scene is simulated in metres east, "
                        "north and up, so give a projected CRS in metres, such as a UTM or MGA zone ('EPSG:7855')")
    return crs.to_wkt("WKT1_GDAL") or crs.to_wkt()


def _metric_projection_problem(crs) -> str | None:
    """Why ``crs`` cannot hold our coordinates (the local frame plus ``origin.offset``, in metres), or
    None. A compound CRS is judged by its horizontal part."""
    horizontal = crs.sub_crs_list[0] if crs.is_compound else crs
    if not horizontal.is_projected:
        return "is geographic, in degrees" if horizontal.is_geographic else "is not a projected CRS"
    units = {axis.unit_name for axis in horizontal.axis_info[:2]}
    if units - {"metre", "meter"}:
        return f"has its axes in {', '.join(sorted(units))}"
    return None


def _proj_reason(error: Exception) -> str:
    """PROJ's own words from a pyproj error, without pyproj's repetition of the input."""
    return str(error).rpartition("proj_create: ")[2].removesuffix(")") or str(error)
