"""The role of each element kind in the energy account: "source", "dissipator", "storage" or
"converter" (a two-port).

>>> ROLES["R"], ROLES["GY"]
('dissipator', 'converter')
"""

ROLES = {"Se": "source", "MSe": "source", "Sf": "source", "MSf": "source", "R": "dissipator",
         "C": "storage", "I": "storage", "TF": "converter", "MTF": "converter", "GY": "converter",
         "MGY": "converter"}
