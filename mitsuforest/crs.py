"""The coordinate reference system of ``origin.crs``: checked by the scene file's validation, written
into LAS, LAZ and COPC headers; and the CRS of a point file read (its units). Imports no stage."""

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


def projection_problem(wkt: str) -> str | None:
    """Why the CRS ``wkt`` cannot be a scene's ``origin.crs`` (:func:`_metric_projection_problem`), or None."""
    import pyproj
    return _metric_projection_problem(pyproj.CRS.from_user_input(wkt))


def file_crs(path) -> str | None:
    """The CRS of a LAS/LAZ file as WKT, or None (a PCD, no CRS, or a CRS record laspy cannot parse,
    which is as good as none to a reader)."""
    if str(path).lower().endswith(".pcd"):
        return None
    import laspy
    try:
        with laspy.open(str(path)) as reader:
            crs = reader.header.parse_crs()
    except Exception:
        return None
    return crs.to_wkt() if crs is not None else None


CRS_RECORDS = {34735: "GeoTIFF keys", 2112: "WKT"}    # LASF_Projection record ids of a CRS


def unread_crs_record(path) -> str | None:
    """The kind of CRS record (``"GeoTIFF keys"``, ``"WKT"``) a LAS/LAZ file holds, for a file whose CRS
    :func:`file_crs` could not read (a user-defined projection's GeoTIFF keys), or None: a PCD, a file
    without one. The caller has asked :func:`file_crs` already (reading the header again costs an open)."""
    if str(path).lower().endswith(".pcd"):
        return None
    import laspy
    try:
        with laspy.open(str(path)) as reader:
            records = [*reader.header.vlrs, *(getattr(reader.header, "evlrs", None) or [])]
    except Exception:
        return None
    return next((CRS_RECORDS[r.record_id] for r in records
                 if r.user_id == "LASF_Projection" and r.record_id in CRS_RECORDS), None)


def length_units(wkt: str) -> tuple[str, str, float, float]:
    """The name of the CRS ``wkt``, its units in words (``"metre"``, ``"foot"``, ``"metre, heights in US
    survey foot"``), and the metres per unit of its x and y and of its heights (0.3048 for feet). Heights
    are in the unit of the vertical axis, or where the CRS has none, in that of x and y (a state plane in
    feet has its heights in feet).

    :raises ValueError: a geographic CRS (x and y in degrees, not lengths), or one without axes.
    """
    import pyproj
    crs = pyproj.CRS.from_user_input(wkt)
    parts = crs.sub_crs_list if crs.is_compound else [crs]
    axes = [a for sub in parts for a in sub.axis_info]
    across = [a for a in axes if a.direction not in ("up", "down")][:2]
    if parts[0].is_geographic or not across:
        units = ", ".join(sorted({a.unit_name for a in across})) or "no axes"
        raise ValueError(f"its CRS ({crs.name}) is geographic: its x and y are in {units}")
    up = next((a for a in axes if a.direction in ("up", "down")), across[0])
    words = across[0].unit_name if up.unit_name == across[0].unit_name else \
        f"{across[0].unit_name}, heights in {up.unit_name}"
    return crs.name, words, across[0].unit_conversion_factor, up.unit_conversion_factor


def _proj_reason(error: Exception) -> str:
    """PROJ's own words from a pyproj error, without pyproj's repetition of the input."""
    return str(error).rpartition("proj_create: ")[2].removesuffix(")") or str(error)
