"""The viewer configurations beside the node: every topic they show is one the node documents and publishes."""
from __future__ import annotations

import json
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _documented_topics() -> set[str]:
    text = (ROOT / "msg_docs" / "topics.md").read_text()
    return {"/" + t.lstrip("/") for t in re.findall(r"^\| `([^`]+)` \|", text, re.M)} | {"/tf", "/tf_static"}


def _topics_of(config: dict) -> set[str]:
    topics: set[str] = set()
    for panel in config["configById"].values():
        topics.update(panel.get("topics", {}))
        topics.update(p["value"].split(".", 1)[0] for p in panel.get("paths", []))
        if "topicToRender" in panel:
            topics.add(panel["topicToRender"])
        if "publish" in panel:
            topics.add(panel["publish"]["poseTopic"])
    return topics


def test_foxglove_layout_names_only_documented_topics() -> None:
    config = json.loads((ROOT / "config" / "tissue_sim.foxglove.json").read_text())
    documented = _documented_topics()
    used = _topics_of(config)
    assert "/tissue/markers" in used and "/tissue/energy" in used
    assert used <= documented, used - documented

    def panels(node: object) -> set[str]:  # every panel the layout places is configured
        if isinstance(node, str):
            return {node}
        return panels(node["first"]) | panels(node["second"])  # type: ignore[index]

    assert panels(config["layout"]) == set(config["configById"])


def test_foxglove_layout_is_shipped_with_the_package() -> None:
    """Installed beside the RViz file (package data and the colcon share/ directory)."""
    setup = (ROOT / "setup.py").read_text()
    assert '"*.json"' in setup and 'glob("config/*.json")' in setup
