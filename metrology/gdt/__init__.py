"""GD&T: the drawing's feature characteristics measured on the part (form, orientation,
location, runout, dimensions), their datum reference frames and composite segments."""
