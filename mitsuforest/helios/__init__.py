"""HELIOS++ both ways: the meshes and XML documents that let HELIOS++ fly our survey over an exported
scene (:mod:`.export`, :mod:`.documents`), and the reading of an existing HELIOS++ survey so that we fly it ourselves
(:mod:`.survey`, :mod:`.parts`, :mod:`.render`).

HELIOS++ facts these modules rely on (HELIOS++ 2.x source, ``src/assetloading``):

- the assets folders are the ``--assets`` given, then ``assets/``; the ``helios`` command that pip
  installs with HELIOS++ 2.x (pyhelios) runs the ``helios++`` binary with the working folder and its
  data folders as ``--assets`` too (and ``--legacyEnergyModel``); the binary alone adds neither;
- the survey's ``platform``, ``scanner`` and ``scene`` attributes are ``PATH#id``; a relative PATH is
  looked up in each assets folder, then the working folder (first match);
- an ``objloader`` ``filepath`` that is absolute is loaded as it is; a relative one only from the first
  assets folder holding it; an ``efilepath`` regular expression is matched from the working folder
  *and* from every assets folder, adding every match (the same file twice when the working folder is
  an assets folder);
- an OBJ's ``mtllib`` is read from the OBJ's own folder; ``helios_reflectance``,
  ``helios_classification`` and ``helios_isGround`` are HELIOS++'s material keys;
- a part's rotate filters compose in order, its last scale and last translate win, and a vertex
  becomes ``R · (s · v) + t``; ``<rot axis angle_deg>`` is a right-handed rotation;
- ``scanAngle_deg`` is half the field of view, as is an oscillating mirror's ``scanAngleMax_deg``; a
  rotating mirror sweeps 2 x ``scanAngleMax_deg`` each scan line and fires only within
  ``scanAngleEffectiveMax_deg`` (and ``scanAngle_deg``) of nadir; ``beamSampleQuality`` q casts
  ``1 + Σ_{i<q} floor(2π i)`` sub-rays (1, 7, 19, 37, 62 ...);
- legs are waypoints: the platform flies from leg i to leg i+1 with leg i's scanner settings.
"""
