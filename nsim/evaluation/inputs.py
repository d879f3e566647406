"""What an evaluation reads, as the stage (``nsim.stages.evaluate``) resolves it: ``EvaluationInputs``.

The core (``nsim.evaluation``) never sees the stage's ``Inputs`` or its ``RunContext``: the stage loads the
renders, and hands over the workspace as an ``ArtifactReader`` (read only: the artifacts the renders name),
the device LPIPS runs on, the seed SfM draws from, and the detector files given on the command line.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

from nsim.evaluation.renders import ArtifactReader, RenderData


@dataclasses.dataclass(frozen=True, eq=False)
class EvaluationInputs:
    """renders: the render artifacts scored, loaded (``load_render``), in the order given; artifacts: reads the
    artifacts they name (their lineage, the test room, recordings, registrations); device: the torch device
    LPIPS runs on (``cpu`` for the tables that score no images); seed: the run's seed (SfM's); onnx: a detector's
    weights (``detection.detector: onnx``); coco_sim / coco_real: detections on the simulated and real frames
    (``detection.detector: coco``)."""

    renders: tuple[RenderData, ...]
    artifacts: ArtifactReader
    device: str
    seed: int
    onnx: Path | None = None
    coco_sim: Path | None = None
    coco_real: Path | None = None
