"""`dream mark`'s local web page: click one point on the end effector in some frames
(`dream.mark_page.server`)."""
