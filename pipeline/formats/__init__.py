"""File formats the pipeline writes (and reads back): MCAP, ROS messages, g2o.

Modules:
    frames_io: the `frames` artifact: keyframe sonar images as a ROS 2 MCAP
        (`frames_codec`: it as the engine's codec of the `frames` output kind).
    projected_cdr: ProjectedSonarImage <-> CDR bytes, straight from numpy arrays.
    map_mcap: `map.mcap` for Foxglove.
    rosmsg: ROS message types and the deterministic MCAP writer.
    g2o: planar pose graphs in g2o / TORO text.
    simulation: a simulated mission written as a ROS 2 MCAP dataset.
    sim_preview: the preview PNG of a simulated mission.
"""
