"""The gallery (workflow/rules/gallery.smk, rule `gallery_experiment`; `snakemake gallery`): evaluated episodes
replayed for people to watch, per row of the main job's and StackCube's tables and per failure class. Which episodes
(`selection`), their exact replay and what is drawn of each step (`render`: a viewer camera on the original robot
beside the views the policy saw), the text over the frames (`overlay`), the slot masks of a slot encoder
(`slots`), the videos (`video`), the contact sheets (`sheet`), and one experiment's gallery from its run files
(`build`)."""
