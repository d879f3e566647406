"""A toy stage for workspace tests: writes a few files derived from its config."""

from __future__ import annotations

import dataclasses
from pathlib import Path

from nsim.config import param
from nsim.workspace.store import Store


@dataclasses.dataclass(frozen=True)
class ToyConfig:
    payload: str = param("hello")
    repeat: int = param(3, ge=1)


def toy_publish(store: Store, cfg: ToyConfig, inputs=None, ref=None, slow_kill_after=None):
    """Publish (or find in the cache) a toy artifact; returns (artifact, cache_hit)."""
    key = store.action_key("toy", 1, cfg, inputs or {}, seed=0)
    if (hit := store.lookup(key)) is not None:
        return hit, True
    with store.publish(kind="capture", stage="toy", version=1, key=key, config=cfg, inputs=inputs, seed=0, ref=ref) as out:
        (out.dir / "sub").mkdir()
        (out.dir / "a.txt").write_text(cfg.payload * cfg.repeat)
        with open(out.dir / "sub" / "b.bin", "wb") as f:
            f.write(bytes(range(256)) * cfg.repeat)
            if slow_kill_after is not None:
                import os
                import signal

                f.flush()
                Path(slow_kill_after).write_text("writing")
                os.kill(os.getpid(), signal.SIGKILL)
        out.summary["n"] = cfg.repeat
    return out.artifact, False
