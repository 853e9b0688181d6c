//! Static maps: validated polygons, walls and bounding walls (issue 53).
