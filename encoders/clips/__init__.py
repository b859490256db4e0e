"""Clips: per-log rendered camera and BEV frames, a clip table cut from captions, splits, previews.

- :mod:`encoders.clips.layout`: the clips folder: every file name, the clip id, the readers of
  ``manifest.json`` and ``clips.parquet``.
- :mod:`encoders.clips.config`: :class:`ClipsConfig` (YAML round trip).
- :mod:`encoders.clips.render`: :func:`render_log`, every per-frame array of one log, once; the BEV
  and camera arrays in :mod:`encoders.clips.render_bev` and :mod:`encoders.clips.render_camera`,
  reuse of a rendering in :mod:`encoders.clips.render_stats`.
- :mod:`encoders.clips.table`: captions → clip rows (``clips.parquet``).
- :mod:`encoders.clips.splits`: train / val / test by log.
- :mod:`encoders.clips.build`: :func:`build_clips`, the ``scenesearch clips`` command's work.
- :mod:`encoders.clips.raster`: BEV layers on top of :mod:`scenes.bev` (map warp, track footprints).
- :mod:`encoders.clips.views`: one clip's views cut from the memory-mapped arrays (numpy only).
- :mod:`encoders.clips.preview`: animated GIF per clip and a still grid; its BEV half in
  :mod:`encoders.clips.preview_bev`, sizes, colours and palette in :mod:`encoders.clips.preview_canvas`.

The torch dataset over a clips folder is :class:`encoders.data.ClipDataset`.
"""
