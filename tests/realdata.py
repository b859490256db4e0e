"""Where the tests find real logs: ``shared/realdata`` beside the checkout (see its README.md).

The folder lies outside the repository, so every test that reads it names it through :data:`REALDATA`
and skips when what it needs is absent.
"""

from __future__ import annotations

from pathlib import Path

#: ``../shared/realdata`` from the repository root: AV2, KITTI tracking and WOMD samples.
REALDATA = Path(__file__).resolve().parents[1].parent / "shared" / "realdata"
