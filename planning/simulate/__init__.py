"""Simulation of the posted programs on a stock model (issue 15): read each program back as a
control would, cut a tri-dexel stock with the tools, and check travel, collisions and the result
against the scan. Modules: ``motion`` (shared data types), ``program`` (the program reader),
``rs274`` (LinuxCNC's interpreter as an independent reader), ``dexel`` (the tri-dexel stock and the
cutting kernels), ``verify`` (the verification stage of the plan)."""
