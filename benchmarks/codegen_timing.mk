# The timing harness of benchmarks/codegen_step.py, built with a generated step's own flags.
#
# Read after the Makefile `czmpc codegen` wrote (its CC, CZMPC_CFLAGS, WARNINGS, CFLAGS,
# INCLUDES, LDFLAGS and LDLIBS apply):
#
#   make -C DIR -f Makefile -f .../codegen_timing.mk codegen_timing HARNESS=.../codegen_timing.c

# A DAQP step's harness also reads czmpc_daqp.h (the problem it sets its own DAQP up from).
codegen_timing: $(HARNESS) libczmpc.a czmpc_step.h czmpc_model.h $(wildcard czmpc_daqp.h)
	$(CC) $(CZMPC_CFLAGS) $(WARNINGS) $(CFLAGS) $(INCLUDES) $(LDFLAGS) -o $@ $(HARNESS) libczmpc.a $(LDLIBS)

# The compile line above, for the benchmark's report.
codegen_timing_flags:
	@echo $(CC) $(CZMPC_CFLAGS) $(CFLAGS)
