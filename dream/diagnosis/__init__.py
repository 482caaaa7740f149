"""Sim-to-real diagnosis: what the nominal robot-and-camera model gets wrong on measured data.

`dream diagnose` calibrates, studies the residuals (`residuals`), fits each effect of the
catalog (`dream.extension`) jointly with the extrinsic (`fit`), keeps those that predict frames
held out of the fit significantly better (`select`), and writes diagnosis.json (`document`)
and a report (`report`); `run` does it on a sequence and writes the report folder.
"""
