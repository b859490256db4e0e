"""Spatio-temporal tagging with the universal BEV embedding E (Segal et al., CoRL 2020).

- :mod:`.attributes`: the vocabulary (:class:`Attribute`, :class:`Region`, metre definitions).
- :mod:`.rasterize`: ground truth per BEV cell from boxes, behaviour labels and junctions;
  :mod:`.targets` writes it into the clips folder (``CLIPS_DIR/logs/<log_id>/bev_attributes.blocks``).
- :mod:`.head`: attribute embeddings A, V = E · A[τ].
- :mod:`.losses`: hard-negative-mined BCE, smooth L1 per pixel and on scene sums, task balancing.
- :mod:`.scene_tags`: pooling over regions, compositions, tag expressions (pure numpy).
- :mod:`.config`: :class:`TagTrainConfig`, kept by every tagging run folder.
- :mod:`.data`, :mod:`.training`: training windows; joint (hook) or stand-alone training; the run files.
- :mod:`.inference`: loading a run's :class:`Tagger` and tagging whole logs.
- :mod:`.ablation`: which BEV inputs the model sees (none, map, lidar, both).
- :mod:`.evaluate`: Tables 1 and 2; :mod:`.extend`: attributes added to a trained model.

Queries over logs (CLI ``tag`` / ``find`` / ``eval-tags``, Python, HTTP) live in :mod:`retrieval.tagging`.
"""
