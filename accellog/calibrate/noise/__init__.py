"""Allan deviation and the fitted noise model of a rate sensor."""
