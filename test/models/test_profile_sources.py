"""The vessel numbers of the profiles, pinned to the sources their comments cite.

Every node that models the vessel (the simulators, the CS Saucer's observer and DP controller,
the ROV's velocity feed-forward) reads one block of its profile, so a number typed wrong there
makes the plant and the controller wrong together and no closed-loop test can notice. These
tests load the profiles the way bringup does (``load_profile``: includes merged, node
parameters over the common ones) and compare what each node gets with the source, quoted here.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from enbarr_core.allocation.fixed import Thruster, allocation_matrix
from enbarr_core.bringup.profile import load_profile

G = 9.81  # m/s^2, the model's gravity (RigidBodyParams.gravity)


def node_parameters(profile: str, node: str) -> dict:
    """What ``node`` of ``profile`` is given: the common parameters, then its own over them."""
    p = load_profile(profile)
    return {**p.parameters, **p.node(node).parameters}


# -- CS Saucer: the technical manual (Solheim 2022) --------------------------------------------
# Section 1.4 "Vessel model", the control design model after Ueland [2016]:
#   eta_dot = R(psi) nu,  M nu_dot + (C + D + D(nu)) nu = tau
#   (1.2) M = [[9.51, 0, 0], [0, 9.51, 0], [0, 0, 0.116]]
#   (1.3) C = [[0, -9.51 r, 0], [9.51 r, 0, 0], [0, 0, 0]]
#   (1.4) D = [[1.96, 0, 0], [0, 1.96, 0], [0, 0, 0.168]]
#   (1.5) D(nu) = [[7.095 |u|, 0, 0], [0, 7.095 |v|, 0], [0, 0, 7.095 |r|]]
MANUAL_M = [9.51, 9.51, 0.116]       # eq. 1.2 [kg, kg, kg m^2]
MANUAL_D = [1.96, 1.96, 0.168]       # eq. 1.4 [N s/m, N s/m, N m s/rad]
MANUAL_DN = [7.095, 7.095, 7.095]    # eq. 1.5, D(nu) = diag(Dn) |nu|
# Section 1.2, Table 1.1 "Technical specification for the CSS":
#   Arduino Mega: "Duty cycle between 4.3 and 9.4 %."
#   Graupner Schottel drive unit II: "Can rotate on the interval [-114 deg, 114 deg]."
MANUAL_DUTY_PERCENT = (4.3, 9.4)
MANUAL_SERVO_DEG = 114.0

SAUCER_MODEL_NODES = ('simulator', 'observer', 'dp_control')


@pytest.mark.parametrize('node', SAUCER_MODEL_NODES)
def test_saucer_model_is_the_manuals(node: str) -> None:
    """Each node that models the Saucer gets eqs. 1.2, 1.4 and 1.5 (Dn typed ten times too
    small, or a diagonal swapped, fails here; the closed loop cannot see it)."""
    v = node_parameters('saucer_sim', node)
    assert v['vessel.inertia'] == MANUAL_M
    assert v['vessel.linear_damping'] == MANUAL_D
    assert v['vessel.nonlinear_damping'] == MANUAL_DN
    assert node_parameters('saucer', node if node != 'simulator' else 'observer')[
        'vessel.inertia'] == MANUAL_M  # the vessel's own profile too


def test_saucer_coriolis_of_the_model_is_eq_1_3() -> None:
    """C(nu) of the model built from the profile is eq. 1.3 at r = 0.7 rad/s."""
    from enbarr_core.models.vessel3dof import Vessel3Dof
    from enbarr_core.models.vessel3dof_params import vessel_from_params
    model = Vessel3Dof(vessel_from_params(node_parameters('saucer_sim', 'simulator')))
    r = 0.7
    np.testing.assert_allclose(model.coriolis([0.3, -0.2, r]),
                               [[0.0, -9.51 * r, 0.0], [9.51 * r, 0.0, 0.0], [0.0, 0.0, 0.0]])


def test_saucer_duty_limits_are_table_1_1() -> None:
    v = node_parameters('saucer_sim', 'pwm')
    assert (v['pwm.duty_min_percent'], v['pwm.duty_max_percent']) == MANUAL_DUTY_PERCENT
    # The calibration tables may not ask for a duty outside the Arduino's range.
    for table in ('pwm.thrust_duty_percent', 'pwm.angle_duty_percent'):
        assert min(v[table]) >= MANUAL_DUTY_PERCENT[0] and max(v[table]) <= MANUAL_DUTY_PERCENT[1]


@pytest.mark.parametrize('node', ('simulator', 'allocation', 'pwm'))
def test_saucer_servo_travel_is_table_1_1(node: str) -> None:
    """+-114 deg = +-1.98968 rad (to the 5 decimals the profile gives: 0.5e-5 rad)."""
    v = node_parameters('saucer_sim', node)
    travel = math.radians(MANUAL_SERVO_DEG)
    for name in v['azimuth_names']:
        assert v[f'azimuths.{name}.angle_min'] == pytest.approx(-travel, abs=0.5e-5)
        assert v[f'azimuths.{name}.angle_max'] == pytest.approx(travel, abs=0.5e-5)
    if node == 'pwm':
        assert min(v['pwm.angle_rad']) == pytest.approx(-travel, abs=0.5e-5)
        assert max(v['pwm.angle_rad']) == pytest.approx(travel, abs=0.5e-5)


# -- Enbarr ROV: T. Wu 2018, BlueROV2 (heavy) --------------------------------------------------
# C.-J. Wu, "6-DoF Modelling and Control of a Remotely Operated Vehicle", Flinders University
# 2018. The thesis itself was not at hand; its identified model is quoted, with that citation,
# by github.com/OsloMet-OceanLab/BlueROV2 (BlueRov_m_script.m, commit f063d7c9: mass, weight,
# buoyancy, CG, inertia, added mass, damping and the thruster configuration matrix) and
# github.com/CentraleNantesROV/bluerov2 (bluerov2_description/specs/hydro.py, commit
# 7edecdae: added mass and damping of the "heavy" frame). Both give the same numbers, NED frame
# (Fossen's negative hydrodynamic derivatives):
#   m_t = 11.5 kg, W = 112.8 N, B = 114.8 N, r_cb = [0 0 0], r_cg = [0 0 0.02] m,
#   I = diag([0.16 0.16 0.16])
#   X_udot Y_vdot Z_wdot K_pdot M_qdot N_rdot = -5.5 -12.7 -14.57 -0.12 -0.12 -0.12
#   Xu Yv Zw Kp Mq Nr                         = -4.03 -6.22 -5.18 -0.07 -0.07 -0.07
#   Xuu Yvv Zww Kpp Mqq Nrr                   = -18.18 -21.66 -36.99 -1.55 -1.55 -1.55
#   tau_k = [0.707 0.707 -0.707 -0.707 0 0 0 0;
#           -0.707 0.707 -0.707 0.707 0 0 0 0;
#            0 0 0 0 -1 1 1 -1;
#            0.06 -0.06 0.06 -0.06 -0.218 -0.218 0.218 0.218;
#            0.06 0.06 -0.06 -0.06 0.120 -0.120 0.120 -0.120;
#           -0.1888 0.1888 0.1888 -0.1888 0 0 0 0]
WU_MASS = 11.5
WU_INERTIA = [0.16, 0.16, 0.16]
WU_ADDED_MASS = [5.5, 12.7, 14.57, 0.12, 0.12, 0.12]
WU_D_LIN = [4.03, 6.22, 5.18, 0.07, 0.07, 0.07]
WU_D_QUAD = [18.18, 21.66, 36.99, 1.55, 1.55, 1.55]
WU_R_CG_NED = [0.0, 0.0, 0.02]
WU_B = 114.8
NED_TO_FLU = np.diag([1.0, -1.0, -1.0])  # a rotation by pi about x


ROV_MODEL_NODES = [('enbarr_sim', 'simulator'), ('enbarr_sim', 'control_loop'),
                   ('enbarr_rov', 'control_loop'), ('enbarr_rov_emulated', 'simulator'),
                   ('enbarr_rov_emulated', 'control_loop'), ('enbarr_teleop', 'control_loop')]


@pytest.mark.parametrize('profile, node', ROV_MODEL_NODES)
def test_rov_vehicle_is_wus(profile: str, node: str) -> None:
    """Mass, inertia, added mass and damping as identified by Wu, in every ROV profile and
    for each node that models the vehicle (the code has no default to fall back on). They are
    diagonals, and NED -> FLU is diag(1, -1, -1) on both the linear and the angular part, so
    T diag(a) T^T = diag(a): the values carry over unchanged; only their sign convention
    differs (Fossen's derivatives are negative, the profile's coefficients positive)."""
    v = node_parameters(profile, node)
    assert v['vehicle.mass'] == WU_MASS
    assert v['vehicle.inertia'] == WU_INERTIA
    assert v['vehicle.added_mass'] == WU_ADDED_MASS
    assert v['vehicle.d_lin'] == WU_D_LIN
    assert v['vehicle.d_quad'] == WU_D_QUAD


@pytest.mark.parametrize('profile', ('enbarr_sim', 'enbarr_rov_emulated'))
def test_rov_cg_is_wus_in_flu_and_trim_is_neutral(profile: str) -> None:
    """r_cg = [0 0 0.02] m NED (2 cm below the CB) is [0 0 -0.02] m in FLU. Wu's vehicle is
    2 N light (B = 114.8 N > W = 112.8 N); the profile trims it neutral on purpose (its
    comment says so): B = m g with the model's g."""
    v = node_parameters(profile, 'simulator')
    np.testing.assert_array_equal(v['vehicle.r_g'], NED_TO_FLU @ WU_R_CG_NED)
    assert v['vehicle.r_b'] == [0.0, 0.0, 0.0]
    assert v['vehicle.buoyancy'] == pytest.approx(WU_MASS * G, abs=1e-9)
    assert WU_B - WU_MASS * G == pytest.approx(2.0, abs=0.02)  # what the trim leaves out


def test_rov_thruster_arms_are_wus() -> None:
    """The profile's layout gives the moment arms of Wu's configuration matrix: 0.1888 m of
    yaw for each vectored thruster (|N| per N of thrust), 0.218 m of roll and 0.120 m of pitch
    for each vertical one, and the 45 deg vectoring (0.707 of each thrust in surge and in
    sway). Wu's 0.06 m roll and pitch arms of the vectored thrusters (they sit below the CO)
    are not in the profile: its thrusters are at z = 0 (its comment says so)."""
    v = node_parameters('enbarr_sim', 'simulator')
    thrusters = [Thruster(n, v[f'thrusters.{n}.position'], v[f'thrusters.{n}.direction'],
                          v[f'thrusters.{n}.max_forward'], v[f'thrusters.{n}.max_reverse'])
                 for n in v['thruster_names']]
    B = allocation_matrix(thrusters)  # columns: [X Y Z K M N] per N of thrust, FLU
    horizontal = [i for i, t in enumerate(thrusters) if abs(t.direction[2]) < 1e-9]
    vertical = [i for i, t in enumerate(thrusters) if abs(abs(t.direction[2]) - 1.0) < 1e-9]
    assert len(horizontal) == 4 and len(vertical) == 4
    for i in horizontal:
        np.testing.assert_allclose(np.abs(B[:2, i]), [0.707, 0.707], atol=5e-4)
        assert abs(B[5, i]) == pytest.approx(0.1888, abs=5e-5)
        np.testing.assert_allclose(B[2:5, i], 0.0, atol=1e-12)  # Wu: 0.06 (not modelled)
    for i in vertical:
        assert abs(B[3, i]) == pytest.approx(0.218, abs=5e-4)
        assert abs(B[4, i]) == pytest.approx(0.120, abs=5e-4)
        np.testing.assert_allclose(B[[0, 1, 5], i], 0.0, atol=1e-12)


def test_rov_thrust_limits_are_the_quoted_kgf() -> None:
    """The profile's comment: 5.25 kgf forward, 4.1 kgf reverse (T200 at 16 V) -> N."""
    v = node_parameters('enbarr_sim', 'simulator')
    for n in v['thruster_names']:
        assert v[f'thrusters.{n}.max_forward'] == pytest.approx(5.25 * 9.80665, abs=0.05)
        assert v[f'thrusters.{n}.max_reverse'] == pytest.approx(4.1 * 9.80665, abs=0.05)


def test_a_non_physical_vessel_names_its_parameter() -> None:
    from enbarr_core.models.vessel3dof_params import vessel_from_params
    v = {'vessel.inertia': [9.51, 0.0, 0.116], 'vessel.linear_damping': [1.96, 1.96, 0.168],
         'vessel.nonlinear_damping': [0.0, 0.0, 0.0]}
    with pytest.raises(ValueError, match=r'^vessel\.inertia: M: inertia must be > 0'):
        vessel_from_params(v)
    with pytest.raises(ValueError, match=r'^vessel\.nonlinear_damping: Dn: damping must be >= 0'):
        vessel_from_params({**v, 'vessel.inertia': [9.51, 9.51, 0.116],
                            'vessel.nonlinear_damping': [0.0, -1.0, 0.0]})
