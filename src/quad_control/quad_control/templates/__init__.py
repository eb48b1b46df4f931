"""Controller templates to copy (docs/plugins.md): `my_controller` in our types, `flightsim_controller` in the
flightsim / rotorpy interface. Both fly as they are, e.g.
`--controller quad_control.templates.my_controller:MyController`."""
