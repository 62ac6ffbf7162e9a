"""softsensor: a virtual sensor for industrial MDF flash dryers.

Folders: ``model`` (pure physics), ``plant`` (the virtual plant), ``ingest`` (Modbus, lab
input), ``recording`` (MCAP days), ``bus`` (Zenoh), ``estimation`` (open loop, UKF),
``service`` (daemon), ``calibration`` and ``diagnosis``; ``cli`` wires them together.
"""

__version__ = "0.1.0"
