"""Interleaved CPU-time profile of heightfield variants in one process (hf_setup.profile).
usage: prof.py scene rounds frames 'name|buildopts|json params|what' ...   (what: frame or horizons)"""
import os, sys
sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))  # hf_setup.py
from hf_setup import profile

profile(sys.argv[1:])
