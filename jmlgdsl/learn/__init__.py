"""Learning a mode bank from experiments: PRBS design (prbs), step-test FOPDT fits (steptest), ARX
least squares for any number of outputs (arx), EM for the state-space model (em), the state basis
every mode of a bank shares and EM inside it (basis), validation (validate), the per-mode pipeline
and bank assembly (bank), the spec writer (writer) and figures (figures)."""
