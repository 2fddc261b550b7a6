"""Batched SO(3) / SE(3) geometry: maps and conversions (:mod:`~lossvo.geometry.maps`), distances
(:mod:`~lossvo.geometry.distances`) and the metric-axioms checks (:mod:`~lossvo.geometry.axioms`; their
table: ``python -m lossvo.axioms``). Conventions are stated in :mod:`lossvo.geometry.maps`.
"""

from lossvo.geometry.distances import euler_distance as euler_distance
from lossvo.geometry.distances import quat_distance as quat_distance
from lossvo.geometry.distances import quat_distance_squared as quat_distance_squared
from lossvo.geometry.distances import rotation_angle as rotation_angle
from lossvo.geometry.distances import se3_chordal_distance as se3_chordal_distance
from lossvo.geometry.distances import so3_chordal_distance as so3_chordal_distance
from lossvo.geometry.distances import so3_geodesic_distance as so3_geodesic_distance
from lossvo.geometry.maps import EULER_CONVENTION as EULER_CONVENTION
from lossvo.geometry.maps import check_shape as check_shape
from lossvo.geometry.maps import consecutive_relative_poses as consecutive_relative_poses
from lossvo.geometry.maps import euler_to_matrix as euler_to_matrix
from lossvo.geometry.maps import hat as hat
from lossvo.geometry.maps import make_pose as make_pose
from lossvo.geometry.maps import matrix_to_euler as matrix_to_euler
from lossvo.geometry.maps import matrix_to_quat as matrix_to_quat
from lossvo.geometry.maps import matrix_to_sixd as matrix_to_sixd
from lossvo.geometry.maps import orthonormalize as orthonormalize
from lossvo.geometry.maps import pose_inverse as pose_inverse
from lossvo.geometry.maps import quat_normalize as quat_normalize
from lossvo.geometry.maps import quat_to_matrix as quat_to_matrix
from lossvo.geometry.maps import relative_pose as relative_pose
from lossvo.geometry.maps import scale_to_length as scale_to_length
from lossvo.geometry.maps import se3_exp as se3_exp
from lossvo.geometry.maps import se3_exp_rt as se3_exp_rt
from lossvo.geometry.maps import se3_log as se3_log
from lossvo.geometry.maps import sixd_to_matrix as sixd_to_matrix
from lossvo.geometry.maps import so3_exp as so3_exp
from lossvo.geometry.maps import so3_left_jacobian as so3_left_jacobian
from lossvo.geometry.maps import so3_left_jacobian_inv as so3_left_jacobian_inv
from lossvo.geometry.maps import so3_log as so3_log
from lossvo.geometry.maps import vee as vee
