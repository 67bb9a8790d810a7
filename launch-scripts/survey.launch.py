"""Revisit's node graph as a ROS 2 Python launch file, for users with ROS 2 installed:

    ros2 launch launch-scripts/survey.launch.py use_sim_time:=true

It starts the same nodes, with the same parameters and remappings, as
`revisit launch launch-scripts/survey.yaml` (the executables `revisit-NODE` on PATH, e.g. from
`cargo install --path nodes/ingest`, and likewise features, places, matcher and mapper).
"""
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node


def generate_launch_description():
    use_sim_time = LaunchConfiguration("use_sim_time")
    return LaunchDescription([
        DeclareLaunchArgument("use_sim_time", default_value="false",
                              description="Follow /clock (revisit bag play --clock)."),
        Node(
            executable="revisit-ingest",
            name="ingest",
            parameters=[{"use_sim_time": use_sim_time, "keyframe.min_overlap": 0.7, "camera": "cam0"}],
            remappings=[
                ("image/compressed", "/camera/image_raw/compressed"),
                ("image", "/camera/image_raw"),
                ("camera_info", "/camera/camera_info"),
            ],
            respawn=True,
            respawn_delay=1.0,
            output="screen",
        ),
        Node(
            executable="revisit-features",
            name="features",
            parameters=[{"use_sim_time": use_sim_time, "state_dir": "revisit-state/features"}],
            respawn=True,
            output="screen",
        ),
        Node(
            executable="revisit-places",
            name="places",
            parameters=[{"use_sim_time": use_sim_time, "state_dir": "revisit-state/places"}],
            respawn=True,
            output="screen",
        ),
        Node(
            executable="revisit-matcher",
            name="matcher",
            parameters=[{"use_sim_time": use_sim_time, "state_dir": "revisit-state/matcher"}],
            respawn=True,
            output="screen",
        ),
        Node(
            executable="revisit-mapper",
            name="mapper",
            parameters=[{"use_sim_time": use_sim_time, "work_dir": "revisit-state/mapper", "frame_id": "map"}],
            respawn=True,
            output="screen",
        ),
    ])
