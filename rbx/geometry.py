"""The geometry of tables, one import for the engine, the tools and the tests: the names of its four rooms.

A table is data, not a class: a list of primitives (:mod:`rbx.primitives`: codes, parameter rows read through
named offsets, the njit kernels of each primitive), the wall each belongs to (``Wall``: names, tangent axes,
sampling patches) and what the kernels read beside them (``Geometry``). The rooms:

- :mod:`rbx.primitives`: the primitives' contracts and kernels (collision time, normal, snap, normal Jacobian,
  the searches, the periodic cell walk);
- :mod:`rbx.pieces`: wall pieces as data and their plane geometry;
- :mod:`rbx.construction`: the builders of the paper's kinds, tables from pieces, obstacles, fit checks;
- :mod:`rbx.drawing`: tables drawn with matplotlib.

Adding a table kind = a builder in :mod:`rbx.construction` (or only its walls), registered with its other facets in
:mod:`rbx.tables`. Adding a primitive = its section in :mod:`rbx.primitives`.
"""
from .construction import (_boundary, _flat_wall, _halfspaces, _trim, _trim_patch, add_pieces, box,  # noqa: F401
                           check_fit, circle, from_pieces, plates, polygon, rectangle, strip, wedge)
from .drawing import draw, draw3d  # noqa: F401
from .pieces import (_angle, _arc_points, _boundary_distance, _caps_z, _ccw_span, _left, _meets,  # noqa: F401
                     _piece_frame, _polygon_clearance, _subtended, _unit2, arcs_cross, boundary_area,
                     boundary_polyline, pieces_clearance)
from .primitives import (CONCAVE_ARC, CONVEX_ARC, CYLINDER, END_TOLERANCE, FOCUS_ARC, HALFSPACE,  # noqa: F401
                         MAX_PERIODIC_FLIGHT, NPARAM, P_LENGTH, P_NORMAL, P_POINT, P_RADIUS, P_TANGENT, P_WIDE,
                         PRIMITIVES, SEGMENT, SPHERE_OUT, Geometry, Wall, _in_arc, _row, box_collision,
                         collision_time, contact_normal, next_collision, normal_jacobian, periodic_flight,
                         periodic_images, slab_collision, snap)
