"""The env horizons, env and total radiance and the image of the two terrain bench scenes for
builds given as arguments (PENUMBRA_CL_BUILD_OPTIONS), compared bit for bit with the first:
the seventh round's script, run as it is."""
import os, runpy
runpy.run_path(os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "speed7_search", "same_bits.py"),
               run_name="__main__")
