"""Pictures of models and motions (matplotlib, Agg; Pillow for GIFs).

- `planar`: side-view (x-z) outlines of collision shapes, obstacles (planes as hatched
  solids), the kinematic skeleton.
- `motion`: `Motion`, a solved problem or sequence joined into one continuous motion
  (the trajectory, contact data, segment labels) with cached forward kinematics.
- `plots`: PNG plots (joint positions, torques, contact forces and distances, x-z paths).
- `animation`: the GIF (and MP4 with ffmpeg) animation.
- `demo`: the main demo (`cstorm demo`: the tumbler sequence).

`cstorm.report.write_outputs` / ``cstorm solve`` and ``cstorm animate`` use them.
"""
