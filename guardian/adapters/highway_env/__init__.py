"""highway-env read as the guardian's scene model.

``road``: the road network as a ``Road`` or ``RoadMap``; ``scene``: the ego and the other cars as a
``Scene`` and the ego's ``EgoState``; ``blindness``: traffic that does not see a guarded car (v0 roads);
``monitor``: does each observed transition fit the model the sets assume (counted, never assumed);
``checks``: which configurations the guardian can supervise.
"""
