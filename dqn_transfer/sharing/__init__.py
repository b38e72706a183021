"""A trained team as others use it: loaded from any run, replica, folder or file (:mod:`.team`), and
exported as a folder with its model card (:mod:`.model_card`)."""
