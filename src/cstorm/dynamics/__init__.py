"""Rigid-body dynamics on kinematic trees: kinematics, RNEA, CRBA, ABA, hybrid dynamics,
point Jacobians, energies, passive joint forces, and the analytic derivatives of RNEA,
ABA and the hybrid dynamics."""

from .kinematics import forward_kinematics, body_velocities, frame_pose
from .rnea import rnea, bias_forces, gravity_forces
from .crba import mass_matrix
from .hybrid import aba, hybrid_dynamics
from .jacobians import point_jacobian
from .energy import kinetic_energy, potential_energy, center_of_mass
from .passive import passive_forces
from .configuration import integrate, difference, normalize
from .derivatives import (
    rnea_derivatives, aba_derivatives, hybrid_dynamics_derivatives, RNEADerivatives, ABADerivatives,
    HybridDerivatives,
)
