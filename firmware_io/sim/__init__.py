"""The simulated hand, split into one small module per physical effect.

The public face is :mod:`firmware_io.simulate`; these modules are its parts:
``constants`` (measured figures), ``streams`` (seeded substreams), ``contact`` (pressure
patches on the pads), ``sensor`` (DSA 9205 transduction and the DSACON32m firmware),
``timing`` (PC time stamps), ``scenario`` (objects, poses, subjects, trial parameters),
``actions`` (what the person does), ``hand`` (renders trials into frames), ``protocol`` and
``session`` (the two ways recordings are assembled).
"""
