"""The role of each element kind in the energy account: "source", "dissipator", "storage" or
"converter" (a two-port), read from the table of kinds (:mod:`bondc.kinds`).

>>> ROLES["R"], ROLES["GY"]
('dissipator', 'converter')
"""

from __future__ import annotations

from bondc.kinds import KINDS

ROLES = {name: kind.energy for name, kind in KINDS.items()}     # the energy role of each kind (bondc.kinds)
