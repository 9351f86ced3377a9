"""Export of a model for other tools: its C code and header (:mod:`bondc.export.ccode`, ``bondc
compile --target c``) and Functional Mock-up Units (:mod:`bondc.export.fmu`, ``bondc fmu``)."""
