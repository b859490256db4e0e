"""Waymo Open Motion Dataset (WOMD) import: ``Scenario`` records in TFRecord files → AV2-layout logs.

Each ``Scenario`` (91 steps at 10 Hz of world-frame boxes, a vector map) becomes one log folder
``womd_<scenario_id>/``::

    annotations.feather            every track but the ego's, valid steps only, ego frame
    city_SE3_egovehicle.feather    the track named by ``sdc_track_index``, valid steps only
    map/log_map_archive_womd_<id>____WOMD_city_0.json   lanes, crossings, drivable areas
    log_metadata.json              source "womd", scenario id, source file and record, counts

Reading needs neither TensorFlow nor Waymo's package: :mod:`scenes.womd.tfrecord` frames the file
and checks both CRC-32C of every record; :mod:`scenes.womd.proto` declares the fields read, under the
public field numbers of ``scenario.proto`` / ``map.proto``, and decodes with ``protobuf``.

Conventions:

- **Time**: ``timestamps_seconds`` × 10⁹, rounded, is ``timestamp_ns`` (scenarios start at 0).
- **Frames**: WOMD's world frame is the city frame. The ego origin is the rear axle on the
  ground, :data:`~scenes.womd.importer.EGO_BOX_CENTER_AHEAD_M` behind the centre of the self-driving
  car's box. Every other box is expressed in the ego frame at its step (``ego_SE3_object``); its
  centre stays the box centre. Boxes are upright: WOMD gives a heading only.
- **Validity**: only states with ``valid`` set are written. A valid state with a non-finite value or
  a non-positive size, or at a step where the self-driving car is not valid (no ego pose to put it
  in), is left out and counted in the report and the metadata.
- **Categories** (:data:`~scenes.womd.importer.WOMD_TO_CATEGORY`; the AV2 label written in brackets):

  ``TYPE_VEHICLE`` → ``car`` (``REGULAR_VEHICLE``; WOMD does not tell cars from trucks or buses),
  ``TYPE_PEDESTRIAN`` → ``pedestrian`` (``PEDESTRIAN``), ``TYPE_CYCLIST`` → ``cyclist``
  (``BICYCLIST``), ``TYPE_OTHER`` → ``other`` (``WHEELED_DEVICE``), ``TYPE_UNSET`` → ``other``,
  counted as unknown.
- **Map**: see :mod:`scenes.womd.roadmap` (lane boundaries derived from centre lines and the
  boundary features, crossings from crosswalk polygons, drivable areas from lanes, road edges and
  driveways).

Bad input raises :class:`~scenes.womd.tfrecord.WomdFormatError` naming the file, the record and the
field; :func:`import_womd_files` lists each skipped scenario with its reason and goes on.
"""

from scenes.womd.importer import (
    EGO_BOX_CENTER_AHEAD_M,
    WOMD_TO_CATEGORY,
    ConvertedTracks,
    ScenarioTracks,
    SkippedScenario,
    WomdImportBatch,
    WomdImportReport,
    convert_tracks,
    import_womd_files,
    import_womd_scenario,
    log_id_for,
    scenario_tracks,
)
from scenes.womd.proto import ObjectType, parse_scenario
from scenes.womd.roadmap import WomdMap, vector_map_from_womd, womd_map_from_features
from scenes.womd.tfrecord import WomdFormatError, crc32c, encode_record, iter_records, masked_crc32c, read_records

__all__ = [
    "EGO_BOX_CENTER_AHEAD_M",
    "WOMD_TO_CATEGORY",
    "ConvertedTracks",
    "ObjectType",
    "ScenarioTracks",
    "SkippedScenario",
    "WomdFormatError",
    "WomdImportBatch",
    "WomdImportReport",
    "WomdMap",
    "convert_tracks",
    "crc32c",
    "encode_record",
    "import_womd_files",
    "import_womd_scenario",
    "iter_records",
    "log_id_for",
    "masked_crc32c",
    "parse_scenario",
    "read_records",
    "scenario_tracks",
    "vector_map_from_womd",
    "womd_map_from_features",
]
