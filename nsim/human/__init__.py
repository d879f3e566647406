"""Human bodies for nsim: the skeleton, motion clips, retargeting and procedural gait.

* ``skeleton``  — the 24-joint nsim body (SMPL joint names, no SMPL data), forward kinematics,
  pose boxes, quaternion helpers (wxyz).
* ``motion``    — ``MotionClip`` (frames of root positions + local rotations), ``LocomotionLoop``
  (root-motion extraction, endless replay at any speed, along any 2D path).
* ``motion_io`` — ``load_motion``: a BVH or DeepMimic file retargeted onto the nsim body.
* ``bvh``       — BVH reader/writer (per-joint Euler orders, unit detection, file:line errors).
* ``deepmimic`` — DeepMimic clips as shipped by the optional pybullet wheel.
* ``retarget``  — any skeleton onto the nsim body by a joint-name map (``nsim/configs/motions/joint_map.yaml``).
* ``gait``      — procedural walk / idle / turn clips; the shipped ``nsim/configs/motions/*.bvh``.

The articulated, textured actor that renders these bodies in the test room is ``nsim.synth.actor``.
Import ``load_motion`` from ``nsim.human.motion_io``: this package imports only the data types,
so importing ``nsim.human.skeleton`` does not load the file readers.
"""

from nsim.human.motion import LocomotionLoop, MotionClip
from nsim.human.skeleton import JOINT_NAMES, PARENTS, Skeleton, forward_kinematics, nsim_skeleton

__all__ = ["JOINT_NAMES", "PARENTS", "LocomotionLoop", "MotionClip", "Skeleton", "forward_kinematics",
           "nsim_skeleton"]
