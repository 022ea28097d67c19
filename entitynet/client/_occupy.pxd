# cython: language_level=3
"""What `_occupy.pyx` shares at C level: `occupy`'s fields without the `Occupation` (for `_cover.pyx`, the
network model's publish cover, which adds its own cells before it builds the one `Occupation`)."""

cdef tuple occupy_parts(path, double s_front, double length, double v, double a, double vmax, networks,
                        double known_until, double margin, double lookahead, tight, double max_validity,
                        double min_validity, bint dead_end_at_path_end, travel, double branch_depth)
