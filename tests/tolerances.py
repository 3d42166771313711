"""Named test tolerances, each with the reason it is what it is."""

#: Exact rewrites of the same float arithmetic (round trips, identities).
IDENTITY_RTOL = 1e-12
#: Paper Table 3 gains are printed with two decimals; the issue allows +-0.06 kW/%.
TABLE3_GAIN_ATOL_KW_PER_PCT = 0.06
#: Table 3 power levels before/after each step: the issue allows +-0.4 kW.
TABLE3_LEVEL_ATOL_KW = 0.4
#: Monte-Carlo estimates (sample moments, rejected fractions) against their exact values:
#: 5 standard errors of the estimator (a false alarm has probability ~6e-7 per check).
SAMPLING_SIGMAS = 5.0
