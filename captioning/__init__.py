"""Rule-based temporal captions from object tracks.

The rules follow the supplementary of "Temporal Object Captioning for Street Scene Videos from
LiDAR Tracks", vectorised over tracks × frames:

- host motion (eq. 1) and direction (eq. 2) per frame: :mod:`captioning.host`;
- neighbour stationarity (eq. 3), baseline lane (eq. 4), lane (eq. 5) and motion (eqs. 6, 7,
  generalised to objects behind the host): :mod:`captioning.neighbors`;
- Savitzky–Golay derivatives per contiguous run and flicker suppression: :mod:`captioning.smoothing`;
- unified tags (eq. 8), host segments and windows: :mod:`captioning.unify`;
- caption text and seeded paraphrases: :mod:`captioning.text`; caption rows per window:
  :mod:`captioning.assemble`;
- each object's own behaviour (parked, stopped, braking, turns, lane changes, blocked by / braking
  for a leader, speed; the simulator's label vocabulary) from its city-frame track and the map:
  :mod:`captioning.behavior`, :mod:`captioning.leaders`; map context (lane, intersection,
  crosswalk, junction kind): :mod:`captioning.map_context`. ``rules: paper`` leaves them out and
  gives the paper's captions exactly;
- the paper's right-positive lateral axis is converted once, in :mod:`captioning.tags`;
- all thresholds: :class:`CaptioningConfig` (:mod:`captioning.config`, ``captioning.yaml``);
- files: :mod:`captioning.pipeline`, written log by log by :mod:`captioning.outputs`, many logs in one
  run: :mod:`captioning.batch`; their columns :mod:`captioning.tables`, published together by
  :mod:`scenesearch_base.publish`; simulator-label agreement and own-behaviour F1:
  :mod:`captioning.agreement`; the per-frame oracle of the paper's rules: :mod:`captioning.reference`.

Every tracked object is tagged wherever it is around the ego (standing ones too, under the default
``rules: behavior``); restricting to what a camera sees is the clip stage's job.

Public API::

    from captioning import CaptioningConfig, caption_log, caption_logs, captions_folder, write_outputs
"""

from captioning.batch import BatchResult, LogSummary, caption_logs
from captioning.config import CaptioningConfig
from captioning.errors import CaptioningError, ConfigError, TrackDataError
from captioning.outputs import CaptionsWriter, captions_folder, write_outputs
from captioning.pipeline import Caption, LogCaptions, caption_arrays, caption_dense, caption_log

__all__ = [
    "BatchResult",
    "Caption",
    "CaptioningConfig",
    "CaptioningError",
    "CaptionsWriter",
    "ConfigError",
    "LogCaptions",
    "LogSummary",
    "TrackDataError",
    "caption_arrays",
    "caption_dense",
    "caption_log",
    "caption_logs",
    "captions_folder",
    "write_outputs",
]
