"""The ColorGrid play server: a person leads in the browser while a follower assists live."""
