"""The largest plant a spec may describe, in one place: generous for any real plant, small enough that
a slip (a stray digit, a wrong unit) is a located error instead of a crash or an exhausted memory."""

MAX_NESTING = 100  # operators, calls and signs inside one another in one expression
MAX_TIME_INDEX = 1000  # the k of h[t-k] or h[k]; only t, t-1 and 0 mean anything, and up to this an error says which
MAX_LET_CHAIN = 20  # lets expanded inside one another (a uses b, which uses c, ...)
MAX_EXPONENT = 100  # a whole-number power of an expression in variables (sympy expands it term by term)
MAX_SIZE = 1000  # rows or columns of eye(), zeros() and ones()
MAX_MODES = 1000
MAX_VARIABLES = 2000  # states (declared and block-internal together), inputs, outputs: each
MAX_STACKED = 20_000_000  # modes × (states or outputs)²: the numbers in one stacked matrix (160 MB)
MAX_DELAY_SAMPLES = 1000  # a fopdt dead time becomes one state per sample: more is almost surely a unit slip
MAX_ORDER = 100  # coefficients of an arx block's a or b
MAX_SD = 1e150  # a standard deviation: its square and sums of squares stay finite numbers
MAX_MAGNITUDE = MAX_SD  # any compiled coefficient, offset or initial mean, for the same reason
MAX_ERRORS = 50  # errors shown for one file; the rest are counted


def check_sd(value: float, pos, report):
    """Report (at pos) a standard deviation so large that its variance would overflow."""
    if value > MAX_SD:
        report.error(f"a standard deviation of {value:g} is too large: at most {MAX_SD:g}, so that variances "
                     "stay finite numbers", pos)
