"""Moving objects from events: segmentation (``segment``), tracks (``tracks``), in-plane turns
(``turn``), world paths (``paths``) and the seeding that starts each object's motion (``seed``)."""
