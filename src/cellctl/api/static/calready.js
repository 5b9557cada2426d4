/* cellctl dashboard: whether the calibration lets each recipe go into production, as the service
   says it (GET /status and the "status" event: calibration.problems and calibration.recipes; GET
   /calibration: problems and current.recipes). A recipe's problems name the command that mends
   each. The set is ready for production only when every recipe is. No DOM here. */

// {ready, shared, byRecipe, notReady, readyNames, count, names}:
//   shared      lines every recipe has (e.g. an expired camera), or the only list without recipes;
//   byRecipe    each not-ready recipe's own further lines (null: the service gave no reason);
//   notReady    the recipes that may not run, readyNames the ones that may;
//   count       how many different problems there are.
export function readiness(problems, recipes) {
  const common = problems || [];
  const names = Object.keys(recipes || {});
  const lists = Object.fromEntries(
    names.map((n) => {
      const r = recipes[n] || {};
      return [n, Array.isArray(r.problems) ? r.problems : r.ready === false ? null : []];
    }),
  );
  const notReady = names.filter((n) => recipes[n].ready === false || (lists[n] && lists[n].length > 0));
  const readyNames = names.filter((n) => !notReady.includes(n));
  const known = names.filter((n) => lists[n] !== null);
  // Shared: the lines in every recipe's list (with several recipes, each list known), a single
  // recipe's whole list, and the lines of `problems` no recipe lists.
  let shared = [];
  if (names.length > 1 && known.length === names.length) {
    shared = lists[names[0]].filter((line) => names.every((n) => lists[n].includes(line)));
  } else if (names.length === 1 && lists[names[0]]) {
    shared = lists[names[0]];
  }
  const listed = new Set(known.flatMap((n) => lists[n]));
  shared = [...new Set([...shared, ...common.filter((l) => !listed.has(l))])];
  const byRecipe = {};
  for (const n of notReady) {
    if (names.length === 1 && lists[n] !== null) continue; // one recipe: its lines are the shared list
    byRecipe[n] = lists[n] === null ? null : lists[n].filter((l) => !shared.includes(l));
  }
  const lines = new Set(shared);
  let unknown = 0;
  for (const n of Object.keys(byRecipe)) {
    if (byRecipe[n] === null) unknown += 1;
    else for (const l of byRecipe[n]) lines.add(l);
  }
  const count = lines.size || unknown; // a recipe given no reason counts only when nothing else is known
  const ready = notReady.length === 0 && shared.length === 0;
  return { ready, shared, byRecipe, notReady, readyNames, count, names };
}

// The headline of `r`: "ready", "NOT READY (2)", or with some recipes ready the ones that are not,
// "NOT READY: door-window (1)".
export function readinessWord(r) {
  if (r.ready) return "ready";
  const some = r.notReady.length > 0 && r.readyNames.length > 0;
  return some ? `NOT READY: ${r.notReady.join(", ")} (${r.count})` : `NOT READY (${r.count})`;
}

// All of `r` as lines of text (a tooltip): the shared lines, each not-ready recipe's own, the ready ones.
export function readinessLines(r) {
  const out = [...r.shared];
  for (const [n, lines] of Object.entries(r.byRecipe)) {
    if (lines === null) out.push(`recipe ${n}: not ready`);
    else if (!lines.length && !r.shared.length) out.push(`recipe ${n}: not ready`);
    else out.push(...lines);
  }
  if (!r.ready && r.readyNames.length) out.push(`ready for production: ${r.readyNames.join(", ")}`);
  return out;
}
