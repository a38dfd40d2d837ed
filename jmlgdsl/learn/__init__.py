"""Learning a mode bank from experiments: PRBS design (prbs), step-test FOPDT fits (steptest), ARX
least squares (arx), EM for the state-space model (em), validation (validate), the per-mode
pipeline and bank assembly (bank), the spec writer (writer) and figures (figures)."""
