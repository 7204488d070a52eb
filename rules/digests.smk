# Each rule's config digest travels with the results folder: every job of a rule reads the rule's digest file
# {results}/.digests/{rule}-{digest}.txt (added to each rule's input in workflow/Snakefile; `rule all` asks for every
# one of them). Editing a key the rule reads names another file, which rule config_digest makes: newer than the
# rule's outputs, so every job of the rule reruns, and what follows. A copied folder, a deleted .snakemake/ or
# another checkout keep that promise (Snakemake's params trigger alone lives in the working directory's
# .snakemake/metadata). Planning writes nothing; a run stopped half-way reruns the rest next time (mtime).
rule config_digest:
    output:
        L.rule_digest(),
    log:
        L.log("config_digest", "{rule}-{digest}"),
    wildcard_constraints:
        rule=r"[a-z][a-z0-9_]*",
        digest=r"[0-9a-f]+",
    localrule: True
    message:
        "Config digest of rule {wildcards.rule}: {wildcards.digest}"
    run:
        frng_digests.write_rule_digest(config, wildcards.rule, output[0], log=log[0])
