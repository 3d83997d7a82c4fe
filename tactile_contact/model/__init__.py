"""The physical model of a skin patch. No ROS import.

- :mod:`.modules`: module types (taxel centres per channel) and bus-unique taxel ids;
- :mod:`.layout`: patch layout YAML (modules, elastomer, sensor, grids, solver options);
- :mod:`.grids`: traction / deflection cell grids and masks;
- :mod:`.sensor`: the taxel capacitor, ΔC [F] ↔ compression δ [m], counts ↔ farads;
- :mod:`.elastic`: Love and Boussinesq–Cerruti kernels and influence matrices;
- :mod:`.indenters`: flat punch and Hertz sphere pressure profiles;
- :mod:`.forward`: forward simulation of presses on a fine grid (the truth for tests).
"""
