"""The browser pages (viser): a person corrects the robot by dragging or pushing the cup, or
takes part in a user study; the only package that imports viser (the ``interact`` extra)."""
