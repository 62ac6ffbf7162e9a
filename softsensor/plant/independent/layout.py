"""Where each number lives in the compiled kernels' arrays: the march state and the parameters.

The compiled flow kernel (:mod:`.flow`) takes one float64 parameter vector ``p`` (length
:data:`N_PAR`) and a state vector ``y`` (length :data:`N_STATE`). Their layouts are defined
here only; Python code fills ``p`` by name through :func:`new_parameters`.

March state (per kg of dry fibre or dry gas):

======= ================================================================== ===============
``IX``  fibre moisture, dry basis                                          kg/kg
``IE``  fibre enthalpy (solid + water + sorption term)                     J/kg dry fibre
``IU``  fibre (floc) velocity; constant in the cyclone                     m/s
``IQ``  heat given to the wall or shell since the stream's start           J/kg dry gas
======= ================================================================== ===============

The gas humidity and enthalpy are not integrated: they follow from the conserved totals
(``Y = Y0 - r (X - X0)``, ``e_g = E0 - r e_f - q`` with ``r = m_fiber / m_gas``), so water and
energy close to rounding along every march.
"""

from __future__ import annotations

import numpy as np

IX, IE, IU, IQ = 0, 1, 2, 3
N_STATE = 4

_NAMES = (
    # kinetics variant and its constants
    "variant",        # 0 REA, 1 characteristic drying curve, 2 two-resistance
    "kappa",          # kinetic multiplier (commissioning x chip batch) [-]
    "k_a", "k_b", "k_c",  # variant constants (see fibre.py)
    # GAB isotherm and heat of sorption
    "gab_xm", "gab_c", "gab_k", "gab_lam", "gab_ec", "gab_ek",
    "q_sorp", "x_sorp",
    # fibre
    "cp_scale",       # dry-fibre heat capacity multiplier [-]
    "a_geo",          # geometric specific surface [m2/kg dry]
    "floc",           # share of the geometric surface open to the gas [-]
    "d_fibre",        # fibre diameter [m]
    "d_floc",         # floc volume-equivalent diameter [m]
    "rho_floc",       # dry floc density [kg/m3]
    "hl_a", "hl_b", "hl_c", "hl_d",  # Haider-Levenspiel constants of the floc sphericity
    # gas stream
    "pressure", "m_dg",  # Pa, kg/mol dry gas
    "cdg0", "cdg1", "cdg2", "cdg3", "cdg4",  # dry-gas cp polynomial
    "ratio",          # m_fiber / m_gas (dry) [-]
    "m_gas",          # dry-gas flow [kg/s]
    "x0", "y0", "e0",  # conserved totals: X0, Y0, E0 = e_g0 + ratio e_f0 (+ q0 = 0)
    "xfer",           # multiplier on gas-fibre heat and mass transfer (fouling, batch) [-]
    # duct geometry
    "diameter", "area",  # m, m2
    # segment
    "mode",           # 0 tube or duct (march in z [m]), 1 cyclone (march in s [-])
    "t_wall",         # wall (deposit) or shell inner temperature [K]
    "hi_factor",      # tube: entry and solids-loading enhancement of the inner h [-]
    "g_eff",          # tube: gravity along the flow [m/s2] (+ opposes the flow)
    "t_hold",         # cyclone: fibre hold-up time [s]
    "ua_g",           # cyclone: shell conductance per dry gas flow [J/(kg K)]
    "u_rel",          # cyclone: gas-fibre relative velocity [m/s]
    "cyc_area",       # cyclone: open strand surface as share of the tube's [-]
)
PAR: dict[str, int] = {name: i for i, name in enumerate(_NAMES)}
N_PAR = len(_NAMES)

# explicit names for the compiled code (numba reads module globals as constants)
P_VARIANT = PAR["variant"]
P_KAPPA = PAR["kappa"]
P_KA, P_KB, P_KC = PAR["k_a"], PAR["k_b"], PAR["k_c"]
P_GAB_XM, P_GAB_C, P_GAB_K = PAR["gab_xm"], PAR["gab_c"], PAR["gab_k"]
P_GAB_LAM, P_GAB_EC, P_GAB_EK = PAR["gab_lam"], PAR["gab_ec"], PAR["gab_ek"]
P_Q_SORP, P_X_SORP = PAR["q_sorp"], PAR["x_sorp"]
P_CP_SCALE, P_A_GEO, P_FLOC = PAR["cp_scale"], PAR["a_geo"], PAR["floc"]
P_D_FIBRE, P_D_FLOC, P_RHO_FLOC = PAR["d_fibre"], PAR["d_floc"], PAR["rho_floc"]
P_HL_A, P_HL_B, P_HL_C, P_HL_D = PAR["hl_a"], PAR["hl_b"], PAR["hl_c"], PAR["hl_d"]
P_PRESSURE, P_M_DG = PAR["pressure"], PAR["m_dg"]
P_CDG = PAR["cdg0"]
P_RATIO, P_M_GAS = PAR["ratio"], PAR["m_gas"]
P_X0, P_Y0, P_E0 = PAR["x0"], PAR["y0"], PAR["e0"]
P_XFER = PAR["xfer"]
P_DIAMETER, P_AREA = PAR["diameter"], PAR["area"]
P_MODE, P_T_WALL, P_HI_FACTOR, P_G_EFF = PAR["mode"], PAR["t_wall"], PAR["hi_factor"], \
    PAR["g_eff"]
P_T_HOLD, P_UA_G, P_U_REL, P_CYC_AREA = PAR["t_hold"], PAR["ua_g"], PAR["u_rel"], \
    PAR["cyc_area"]

MODE_TUBE = 0.0
MODE_CYCLONE = 1.0


def new_parameters(**values: float) -> np.ndarray:
    """A parameter vector with the named entries set (the rest zero)."""
    p = np.zeros(N_PAR)
    for name, v in values.items():
        p[PAR[name]] = v
    return p
