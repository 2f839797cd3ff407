"""The Foxglove layout shipped as `configs/foxglove/sonarmap-layout.json`, built with
foxglove-sdk's layout classes (`foxglove.layouts`) so its format is the SDK's own.

Regenerate the file with `python -m sonarmap.pipeline.formats.foxglove_layout > FILE`; a test
checks that the shipped file is this module's output.
"""

from __future__ import annotations

import json
from typing import Any

from sonarmap.pipeline.package_data import configs_dir

__all__ = ["LAYOUT_PATH", "layout_json", "sonarmap_layout"]

LAYOUT_PATH = configs_dir() / "foxglove" / "sonarmap-layout.json"


def sonarmap_layout() -> Any:
    """3D panel (maps, trajectories, objects, mesh, grid) beside the two fan images."""
    import foxglove.layouts as fl

    def cloud(visible: bool, field: str) -> Any:
        return fl.BaseRendererPointCloudTopicSettings(
            visible=visible,
            color_mode="colormap",
            color_field=field,
            color_map="turbo",
            point_size=3.0,
        )

    def path(colour: str, width: float) -> Any:
        return fl.BaseRendererPosesTopicSettings(
            visible=True, type="line", line_width=width, gradient=(colour, colour)
        )

    three_d = fl.ThreeDeePanel(
        title="map",
        config=fl.ThreeDeeConfig(
            follow_tf="map",
            follow_mode="follow-none",
            camera_state=fl.ThreeDeeCameraState(
                distance=60.0,
                perspective=True,
                phi=50.0,
                theta_offset=45.0,
                target_offset=(0.0, 0.0, 0.0),
                fovy=45.0,
                near=0.5,
                far=5000.0,
            ),
            scene=fl.BaseRendererSceneSettings(background_color="#101418"),
            topics={
                "/map/semantic": cloud(True, "class_id"),
                "/map/standard": cloud(False, "z"),
                "/live/fused": cloud(False, "z"),
                "/map/preview": cloud(True, "z"),
                "/trajectory/slam": path("#00ff88ff", 0.15),
                "/trajectory/dead_reckoning": path("#ffaa00ff", 0.1),
                "/trajectory/ground_truth": path("#ffffffaa", 0.1),
                "/trajectory/preview": path("#ff44ccff", 0.15),
                "/objects": fl.BaseRendererSceneUpdateTopicSettings(visible=True),
                "/ground_truth/mesh": fl.BaseRendererSceneUpdateTopicSettings(visible=True),
            },
            layers={
                "grid": fl.BaseRendererGridLayerSettings(
                    layer_id="foxglove.Grid",
                    visible=True,
                    frame_id="map",
                    size=100.0,
                    divisions=20.0,
                    color="#ffffff22",
                )
            },
        ),
    )

    def fan(sonar: str) -> Any:
        mode = fl.ImageModeConfig(image_topic=f"/sonar/{sonar}/fan", color_mode="gradient")
        return fl.ImagePanel(title=f"{sonar} sonar", config=fl.ImageConfig(image_mode=mode))

    images = fl.SplitContainer(
        direction="column",
        items=[fl.SplitItem(content=fan("horizontal")), fl.SplitItem(content=fan("vertical"))],
    )
    return fl.Layout(
        content=fl.SplitContainer(
            direction="row",
            items=[fl.SplitItem(proportion=2, content=three_d), fl.SplitItem(content=images)],
        )
    )


def layout_json() -> str:
    """The layout as the shipped file holds it (the SDK's JSON, indented, newline)."""
    return json.dumps(json.loads(sonarmap_layout().to_json()), indent=2) + "\n"


if __name__ == "__main__":
    print(layout_json(), end="")
