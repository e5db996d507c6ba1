"""Studies above the library: they use it, the library never imports them."""
