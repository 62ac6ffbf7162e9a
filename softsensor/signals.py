"""Names fixed by ``docs/interface.md`` (cited as "CONTRACT section N"): signals, topics, Zenoh
keys, diagnosis causes.

Everything inside the program is SI: temperatures in K, flows in kg/s, humidity ratios and
moistures in kg/kg (dry basis), ``flap_cmd`` in percent.
"""

#: Signals read from the PLC on every scan (CONTRACT section 1), with their SI unit.
SCAN_SIGNALS: dict[str, str] = {
    "T_air_in": "K",
    "m_air": "kg/s",
    "m_fiber": "kg/s",
    "T_fiber_in": "K",
    "m_steam": "kg/s",
    "T_amb": "K",
    "H_amb": "kg/kg",
    "flap_cmd": "%",
    "T_sp": "K",
    "T_dryer_out": "K",
    "T_cyclone_out": "K",
}

#: Model inputs, in the order of the last axis of an input array (see ``softsensor.model``).
#: ``moisture_in`` is not measured; estimators supply it.
INPUT_NAMES: tuple[str, ...] = (
    "T_air_in",
    "m_air",
    "m_fiber",
    "T_fiber_in",
    "m_steam",
    "T_amb",
    "H_amb",
    "moisture_in",
)

#: Model outputs compared with measurements, in the order of an output array's last axis.
OUTPUT_NAMES: tuple[str, ...] = ("T_dryer_out", "T_cyclone_out", "moisture_out")

#: Output channels measured in kelvin (the others are moistures in kg/kg).
KELVIN_CHANNELS: tuple[str, ...] = ("T_dryer_out", "T_cyclone_out")

LAB_SIGNAL = "moisture_out"

# MCAP topics (CONTRACT section 2)
TOPIC_SCAN = "/plant/scan"
TOPIC_LAB = "/plant/lab"
TOPIC_ESTIMATE = "/softsensor/estimate"
TOPIC_HEALTH = "/softsensor/health"
TOPIC_TRUTH = "/truth/plant"
#: The set-point advisor's advice (the project's own topic, docs/interface.md).
TOPIC_ADVICE = "/softsensor/advice"

HEALTH_STATES: tuple[str, ...] = ("ok", "degraded", "stale")


def zenoh_key(kind: str, unit: str = "dryer1") -> str:
    """Zenoh key expression of CONTRACT section 3 for ``kind`` in scan/lab/estimate/health,
    and the project's own ``advice`` (``softsensor/<unit>/advice``, docs/interface.md)."""
    prefix = {"scan": "plant", "lab": "plant", "estimate": "softsensor", "health": "softsensor",
              "advice": "softsensor"}
    if kind not in prefix:
        raise ValueError(f"unknown Zenoh key kind {kind!r}")
    return f"{prefix[kind]}/{unit}/{kind}"


#: Causes the diagnosis can name (CONTRACT section 5).
CAUSES: tuple[str, ...] = (
    "none",
    "inlet_moisture",
    "sensor_bias",
    "lab_delay",
    "fouling_drift",
    "input_lag",
    "ambient_heat_loss",
    "unexplained",
)

#: Causes the virtual plants can inject with ``softsensor simulate --effect``: every cause
#: but ``none`` (``unexplained`` as alternating chip batches).
INJECTABLE_EFFECTS: tuple[str, ...] = CAUSES[1:]
