"""Write (or check) the tiny demo's expected artifact ids for the bit-stable stages.

    python scripts/demo_ids.py --workspace W            # print what W's demo refs would commit
    python scripts/demo_ids.py --workspace W --write    # write tests/data/demo_ids.json from W
    python scripts/demo_ids.py --workspace W --check    # exit 1 naming each ref that differs

W is a workspace made by ``python pipelines/demo.py --preset tiny --workspace W``. The file holds, per demo ref
whose stage is bit-stable (``BIT_STABLE`` in ``nsim/stages/__init__.py``), the artifact id and the digest of its
files alone (``content``), with the code fingerprint (nsim, torch, numpy, pycolmap versions) the ids were made
under: ids also cover that fingerprint, the content digests do not. ``tests/test_demo.py`` checks a fresh tiny
demo against it, so a change that breaks cross-machine reproducibility fails where the developer sees it.
Regenerate it only when a stage's output changes on purpose (and bump that stage's ``VERSION``).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from nsim.stages import stable_ids  # noqa: E402
from nsim.workspace.fingerprint import code_fingerprint  # noqa: E402
from nsim.workspace.store import Store  # noqa: E402

EXPECTED = REPO / "tests" / "data" / "demo_ids.json"


def demo_refs(store: Store) -> dict[str, str]:
    return {name: art for name, art in store.refs().items() if "/demo" in name}


def collect(ws: Path) -> dict:
    store = Store(ws, create=False)
    return {"fingerprint": code_fingerprint(), "refs": stable_ids(store, demo_refs(store))}


def differences(expected: dict, got: dict) -> list[str]:
    """One line per ref whose content (always) or id (under the same code fingerprint) differs."""
    same_code = expected.get("fingerprint") == got.get("fingerprint")
    out = []
    for ref, want in expected["refs"].items():
        have = got["refs"].get(ref)
        if have is None:
            out.append(f"{ref}: missing (stage {want['stage']})")
        elif have["content"] != want["content"]:
            out.append(f"{ref}: {want['stage']} wrote other files ({have['id'][:12]}, expected {want['id'][:12]})")
        elif same_code and have["id"] != want["id"]:
            out.append(f"{ref}: {want['stage']} id {have['id'][:12]}, expected {want['id'][:12]} (same files: the "
                       "manifest differs: config, inputs or summary)")
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--workspace", type=Path, required=True)
    ap.add_argument("--write", action="store_true", help=f"write {EXPECTED.relative_to(REPO)}")
    ap.add_argument("--check", action="store_true", help=f"compare with {EXPECTED.relative_to(REPO)}")
    args = ap.parse_args()
    if not (args.workspace / "nsim-workspace.json").is_file():
        print(f"error: {args.workspace}: not an nsim workspace", file=sys.stderr)
        return 2
    got = collect(args.workspace)
    if args.check:
        diff = differences(json.loads(EXPECTED.read_text()), got)
        for line in diff:
            print(line)
        return 1 if diff else 0
    text = json.dumps(got, indent=1, sort_keys=True) + "\n"
    if args.write:
        EXPECTED.write_text(text)
        print(f"wrote {EXPECTED} ({len(got['refs'])} refs)")
    else:
        print(text, end="")
    return 0


if __name__ == "__main__":
    sys.exit(main())
